"""The Ember RenderEngine: export, render progressively, write the result.

Blender calls ``render`` once per view layer (and per frame of an animation)
with an evaluated depsgraph.  All bpy reads happen in ``export`` before the
renderer starts; the renderer only calls back with finished passes.
Exceptions never escape: Blender would print them and keep a black image, so
they are reported with ``self.report({'ERROR'}, ...)`` and recorded in
``RENDER_LOG`` (which tests and the benchmark read).
"""
import dataclasses
import threading
import time
import traceback

import bpy

from . import backend, output, shards
from . import passes as render_passes
from .export import camera as camera_export
from .export import scene as scene_export

# Facts about recent render() calls (one per view layer and frame): layer,
# error, warnings, timings.  Kept short; the last entry is the latest render.
RENDER_LOG = []
MAX_LOG = 32


class EmberRenderEngine(bpy.types.RenderEngine):
    bl_idname = 'EMBER'
    bl_label = "Ember"
    bl_use_preview = True
    bl_use_spherical_stereo = True   # engine/stereo.py, as Cycles
    bl_use_postprocess = True
    # Keep Blender's shader nodes: Ember reads Cycles/EEVEE material trees.
    bl_use_shading_nodes_custom = False
    # Material Preview shading uses EEVEE; Rendered shading is Ember's own
    # (view_update / view_draw, addon/viewport.py).
    bl_use_eevee_viewport = True

    def __init__(self, *args, **kwargs):
        # Blender 4.4+ passes arguments here; older versions pass none.
        super().__init__(*args, **kwargs)
        self.viewport = None
        self.mesh_cache = None     # Persistent Data: export.persistent.MeshCache

    def __del__(self):
        try:
            viewport_session = self.viewport
        except (AttributeError, ReferenceError):  # Blender freed the struct first
            return
        if viewport_session is not None:
            viewport_session.close()

    def view_update(self, context, depsgraph):
        from . import viewport  # lazy: only for the Rendered viewport (keeps registration at ~30 ms)
        try:
            if self.viewport is None:
                self.viewport = viewport.ViewportSession(self)
            self.viewport.view_update(context, depsgraph)
        except Exception as err:  # noqa: BLE001 - shown in the viewport header
            traceback.print_exc()
            self.update_stats("", "Ember: " + _message(err))

    def view_draw(self, context, depsgraph):
        if self.viewport is None:
            return
        try:
            self.viewport.view_draw(context, depsgraph)
        except Exception as err:  # noqa: BLE001
            traceback.print_exc()
            self.update_stats("", "Ember: " + _message(err))

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", 'COLOR')
        # Depth, Normal and the other Cycles-named passes: addon/passes.py.
        render_passes.register_passes(self, scene, renderlayer)
        if scene.ember.use_denoising:
            self.register_pass(scene, renderlayer, "Noisy Image", 4, "RGBA", 'COLOR')

    def render(self, depsgraph):
        info = {'layer': depsgraph.view_layer.name, 'frame': depsgraph.scene.frame_current,
                'error': None, 'warnings': [], 'started': time.perf_counter(),
                'preview': self.is_preview, 'passes': 0, 'cpu_started': time.process_time()}
        RENDER_LOG.append(info)
        del RENDER_LOG[:-MAX_LOG]
        try:
            self._render(depsgraph, info)
        except Exception as err:  # noqa: BLE001 - every failure must reach the user
            message = _message(err)
            info['error'] = message
            info['traceback'] = traceback.format_exc()
            print(info['traceback'])
            self.report({'ERROR'}, "Ember: " + message)
            self.update_stats("", "Ember: " + message)  # the status bar says why the image is empty
        if bpy.app.background and bpy.app.binary_path:
            _settle_compiler()
        info['seconds'] = time.perf_counter() - info['started']
        info['cpu_seconds'] = time.process_time() - info['cpu_started']

    def _render(self, depsgraph, info):
        scene = depsgraph.scene
        self.update_stats("", "Ember: exporting scene")
        try:
            exported = scene_export.export_scene(depsgraph, self.camera_override,
                                                 should_stop=lambda: output.break_requested(self),
                                                 engine=self, is_preview=self.is_preview,
                                                 cache=self._mesh_cache(scene))
        except scene_export.ExportCancelled:
            info['cancelled'] = True
            return
        info.update(export_seconds=exported.seconds, triangles=exported.triangles,
                    warnings=list(exported.warnings))
        if self.mesh_cache is not None:
            info.update(meshes_reused=self.mesh_cache.reused, meshes_exported=self.mesh_cache.exported)
        if not self.is_preview:
            for warning in exported.warnings:
                self.report({'WARNING'}, "Ember: " + warning)
        settings = scene_export.render_settings(scene, self.is_preview)
        if not self.is_preview:
            settings = _with_passes(settings, scene, depsgraph.view_layer)
        _, _, width, height = camera_export.border_window(scene.render)
        backend.require_ray_tracer()
        render = shards.wrap(backend.engine().render, scene, depsgraph.view_layer.name, self.is_preview)
        if self.test_break():
            info['cancelled'] = True   # Esc between export and the first pass
            return
        if not self.is_preview:
            render_passes.add_result_passes(self, depsgraph.view_layer)
        views = output.result_views(self, width, height, depsgraph.view_layer.name)
        camera_object = scene_export.scene_camera(depsgraph, self.camera_override) if any(views) else None
        for view in views:
            scene_for_view = exported.scene
            if camera_object is not None:   # stereo / multiview: each view its own camera, as Cycles
                self.active_view_set(view)
                scene_for_view = dataclasses.replace(exported.scene, camera=camera_export.view_camera(
                    self, camera_object, exported.scene.camera, view))
            self._render_view(depsgraph, scene_for_view, settings, render, info, width, height, view,
                              report=view == views[-1])
            if info.get('cancelled'):
                return

    def _render_view(self, depsgraph, scene_data, settings, render, info, width, height, view, report=True):
        """Render one view (the only one without multiview) into its result;
        ``report``: this view's warnings go to the user (the last view's,
        so a stereo render names each once)."""
        scene = depsgraph.scene
        writer = output.ResultWriter(self, width, height, depsgraph.view_layer.name, view)
        progress = output.Progress(self, writer, settings.samples, info)
        try:
            backend.engine().validate_scene(scene_data)
            try:
                result = render(scene_data, settings, progress)
            except backend.engine().Cancelled:  # Esc before the first pass
                info['cancelled'] = True
                return
            # A stopped render returns its partial image: write it either way.
            image = result.image
            extra = _extra_passes(result, depsgraph.view_layer, settings.samples)
            if scene.ember.use_denoising and not self.is_preview:
                image, extra = self._denoised(result, extra, info)
            if extra or not progress.cancelled or not info['passes'] or image is not result.image:
                writer.write(image, extra)  # else the last pass written is the image
            writer.add_metadata(render_passes.crypto_metadata(
                depsgraph.view_layer, getattr(result, 'pass_metadata', None) or {}))
            writer.add_metadata(_kernel_metadata(result))
        finally:
            writer.finish()
        info.update(samples=getattr(result, 'samples', progress.samples_done),
                    cancelled=progress.cancelled, stats=dict(getattr(result, 'stats', {}) or {}))
        for warning in getattr(result, 'warnings', None) or () if report else ():
            info['warnings'].append(warning)
            if not self.is_preview:
                self.report({'WARNING'}, "Ember: " + warning)
        if writer.nonfinite:
            message = f"Ember: {writer.nonfinite} non-finite pixel values were replaced by 0"
            info['warnings'].append(message)
            self.report({'WARNING'}, message)

    def _mesh_cache(self, scene):
        """Persistent Data: the meshes kept from this engine's last render
        (Blender keeps the engine between frames with the option on); off,
        nothing is kept."""
        from .export import persistent  # lazy: only for Persistent Data
        if not scene_export.persistent_data(scene, self.is_preview):
            self.mesh_cache = None
        elif self.mesh_cache is None:
            self.mesh_cache = persistent.MeshCache()
        return self.mesh_cache

    def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
        from . import bake  # lazy: only when baking
        bake.bake(self, depsgraph, obj, pass_type, pass_filter, width, height)

    def _denoised(self, result, extra, info):
        """Combined denoised (alpha kept), the raw image as Noisy Image.  A
        denoiser failure keeps the noisy image and says why."""
        from . import denoise  # lazy: only when denoising (subprocess, ctypes: keeps registration cheap)
        self.update_stats("", "Ember: denoising")
        start = time.perf_counter()
        try:
            rgb = denoise.denoise(result.image[..., :3], result.albedo, result.normal)
        except (denoise.DenoiseError, OSError, ValueError) as err:
            message = f"Ember: denoising failed, the image is not denoised: {err}"
            info['warnings'].append(message)
            self.report({'WARNING'}, message)
            return result.image, extra
        info['denoise_seconds'] = time.perf_counter() - start
        info['denoiser'] = denoise.describe()
        image = result.image.copy()
        image[..., :3] = rgb
        return image, dict(extra, **{'Noisy Image': result.image})


def _settle_compiler():
    """A command-line render in Blender's binary ends its kernel compile
    thread before Blender quits: Blender's exit walks sys.modules
    (addon_utils.disable_all) and fails with "dictionary changed size
    during iteration" if that thread is still importing numba."""
    try:
        backend.engine().stop_kernels()
    except ImportError:
        pass


def _kernel_metadata(result):
    """Which kernels rendered the image (compiled or NumPy: they round
    differently), in the result's metadata as 'Ember Kernels'."""
    mode = (getattr(result, 'stats', None) or {}).get('kernels')
    return {'Ember Kernels': mode} if mode else {}


def _extra_passes(result, view_layer, samples):
    """{Blender pass name: image} (the engine's Cycles-named passes)."""
    return render_passes.blender_images(view_layer, getattr(result, 'passes', None) or {}, samples)


def _with_passes(settings, scene, view_layer):
    """The render settings with the passes this view layer asks for."""
    names = render_passes.engine_passes(view_layer)
    if not names or not hasattr(settings, 'passes'):
        return settings
    config = render_passes.pass_config(scene, view_layer, backend.engine().PassConfig)
    return dataclasses.replace(settings, passes=names, pass_config=config)


def _message(err):
    text = str(err).strip() or type(err).__name__
    if isinstance(err, (scene_export.ExportError, ValueError)):
        return text
    return f"{type(err).__name__}: {text}"


classes = (EmberRenderEngine,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    if not bpy.app.background:
        bpy.app.timers.register(_warm_kernels, first_interval=2.0)


def _warm_kernels():
    """Soon after the add-on is enabled, make the kernels ready in the
    background: compile them once per Ember version (after an install or
    update; 'Compiling kernels' in the status bar while an F12 waits), and
    in later sessions load them from the disk cache, so that the first F12
    of a session does not wait for that either (1-2 s: it was 2.4x the
    CPU of a later 64x64 render, docs/benchmarks.md)."""
    try:
        renderer = backend.engine()
        complete = renderer.kernel_cache_complete()   # also True with the JIT off: then only imports
        backend.require_ray_tracer()   # embreex with its own Embree, in this thread
        threading.Thread(target=_warm_quietly, args=(renderer, not complete), name="ember-warm",
                         daemon=True).start()
    except Exception as err:  # noqa: BLE001 - a render compiles them anyway, and says so
        print(f"Ember: kernels not compiled ahead: {_message(err)}")
    return None


def _warm_quietly(renderer, say_why=True):
    try:
        renderer.warm_kernel_cache()
    except Exception as err:  # noqa: BLE001 - a render compiles them anyway, and says so
        if say_why:
            print(f"Ember: kernels not compiled ahead: {_message(err)}")


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
