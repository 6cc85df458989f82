"""The add-on's version, for modules of the package that record it (render-farm
shards).  ``bl_info`` in __init__.py must stay a literal Blender can read
without importing the package, so the number is written twice;
tests/engine/test_imports.py checks that the two agree."""
VERSION = (0, 1, 0)
