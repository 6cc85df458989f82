"""Ember render farm: animations and sample-split frames on Dask.

    python -m farm render SCENE.blend --frames 1-250 (--scheduler tcp://HOST:8786 | --local N) -o OUT
    python -m farm worker tcp://HOST:8786
    python -m farm merge SHARD... -o OUT.exr
    python -m farm status --scheduler tcp://HOST:8786

Modules: ``plan`` (frames, chunks, sample ranges, file names, what is left
to do), ``commands`` (Blender command lines), ``tasks`` (what a worker runs:
one Blender subprocess per task), ``shardfile`` and ``merge`` (film states
and their exact combination), ``client`` (submission, retries, progress),
``worker`` (a Dask worker with one render slot), ``versions`` (the Ember,
Blender and scene a task refuses to render without), ``status`` (jobs,
tasks, workers and ETA from the scheduler), ``flamenco/ember.js``.
Importing the package imports neither Dask nor bpy.
"""
