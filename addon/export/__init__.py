"""Blender data -> engine.scene: the only place that reads bpy for rendering.

Each module translates one kind of data block; ``scene.export_scene`` ties
them together.  Every function returns plain NumPy arrays and engine.scene
dataclasses, so the renderer never sees bpy and no bpy data is touched from a
worker thread.
"""
