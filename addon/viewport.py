"""The Rendered viewport: incremental export, a render thread, drawing.

Blender calls ``view_update`` when the depsgraph changed and ``view_draw``
whenever the region redraws, both on the main thread.  Everything that reads
bpy happens there: ``SceneCache`` turns the depsgraph updates into plain
engine data, re-exporting only what changed (a moved object re-walks the
instances for their matrices and exports no mesh; an edited material is
translated again, alone), and ``viewport_camera`` builds the view's camera
from the region.  ``RenderThread`` renders that data with the ordinary engine
entry point, first at a reduced resolution and then refining to full
resolution and the Viewport Samples, after which it stops (pauses) until
something changes.  ``view_draw`` draws the latest image as scene-linear
floats through Blender's display-space shader, so colour management changes
only redraw.  A timer on the main thread tags the region for redraw when the
thread has a new image: the thread never touches bpy.
"""
import dataclasses
import threading
import weakref
import time
import traceback

import bpy
import numpy as np

from . import backend, denoise
from .export import camera as camera_export
from .export import instances as instance_export
from .export import light as light_export
from .export import material as material_export
from .export import scene as scene_export
from .export import world as world_export

# The first picture after a change covers at most this many pixels: it must
# appear within a fraction of a second on two cores.
FIRST_PASS_PIXELS = 160 * 90
RESIZE_DELAY = 0.3        # seconds a new region size must hold before restarting
REDRAW_INTERVAL = 0.05    # how often the main-thread timer looks for a new image
HALF_MAX = 65504.0        # largest finite half float (the texture is RGBA16F)

# Counters and timings of every viewport session (tests and users read them).
STATS = {}
# Live sessions (tests look at their state).
SESSIONS = weakref.WeakSet()


def reset_stats():
    STATS.update(mesh_exports=0, material_exports=0, world_exports=0, syncs=0, restarts=0,
                 first_image_seconds=[], first_draw_seconds=[], errors=[])


reset_stats()


# -- incremental export ------------------------------------------------------

class SceneCache:
    """The engine scene of a viewport, kept between depsgraph updates."""

    def __init__(self):
        self.mesh_of_key = {}      # geometry key -> mesh index in self.meshes (or None)
        self.meshes = []
        self.materials = material_export.MaterialTable()
        self.instances = []
        self.points = []        # engine PointClouds of the last walk
        self.lights = []
        self.world = None
        self.warnings = []
        self.version = 0           # bumps whenever a mesh, material or the world is (re)exported
        self.signature = None
        self._world_key = None

    def sync(self, depsgraph, first=False):
        """Apply the depsgraph's updates; returns True if the picture's input
        changed (selection and other updates that change nothing return False)."""
        STATS['syncs'] += 1
        stale_geometry = set()
        for update in () if first else depsgraph.updates:
            ident = update.id
            kind = type(ident).__name__
            if kind == 'Object' and update.is_updated_geometry:
                stale_geometry.update(_geometry_keys(ident))
            elif kind == 'Mesh' and update.is_updated_geometry:
                stale_geometry.add(ident.as_pointer())
            elif kind == 'Material':
                self._refresh_material(ident)
            elif kind == 'Image' or (kind == 'ShaderNodeTree'
                                     and not getattr(ident, 'is_embedded_data', False)):
                # Node groups and images may be shared by any material.  (A
                # material's own tree arrives with the Material update.)
                self._refresh_all_materials()
            elif kind == 'World':
                self._export_world(depsgraph)
        if first or self._world_changed(depsgraph):
            self._export_world(depsgraph)
        override = getattr(depsgraph.view_layer, 'material_override', None)
        if override != self.materials.override:
            self.materials = material_export.MaterialTable(override)
            self.version += 1
        for key in stale_geometry:
            self.mesh_of_key.pop(key, None)
        self._walk(depsgraph)
        signature = (self.version, self._placements())
        changed = signature != self.signature
        self.signature = signature
        return changed

    def _walk(self, depsgraph):
        """Instances, their matrices and lights; meshes only where not cached."""
        self.materials.slots_cache.clear()  # slot assignments may have changed
        collector = instance_export.InstanceCollector(self.materials.slots,
                                                      view_layer=getattr(depsgraph, 'view_layer', None),
                                                      scene=getattr(depsgraph, 'scene', None), render=False)
        collector.meshes, collector.mesh_of_key = self.meshes, self.mesh_of_key
        meshes_before = len(self.mesh_of_key)
        materials_before = len(self.materials.materials)
        seen = set()
        original = collector._mesh_id

        def mesh_id(obj):
            seen.add(obj.data.as_pointer() if obj.type == 'MESH' else ('object', obj.name_full))
            return original(obj)
        collector._mesh_id = mesh_id
        for inst in depsgraph.object_instances:
            collector.add(inst)
        exported = len(self.mesh_of_key) - meshes_before
        STATS['mesh_exports'] += exported
        STATS['material_exports'] += len(self.materials.materials) - materials_before
        self.version += exported + len(self.materials.materials) - materials_before
        # Forget geometry no longer used: its data block may be freed and its
        # address reused by another mesh.
        for key in [k for k in self.mesh_of_key if k not in seen]:
            del self.mesh_of_key[key]
        self.instances = collector.instances
        self.points = collector.points
        self._compact()
        self.lights, self.warnings = light_export.collect_lights(depsgraph)

    def _compact(self):
        """Drop meshes no key refers to any more (replaced by a geometry edit,
        or their object gone), so long editing sessions do not pile them up."""
        live = sorted({i for i in self.mesh_of_key.values() if i is not None})
        if len(live) == len(self.meshes):
            return
        remap = {old: new for new, old in enumerate(live)}
        self.meshes[:] = [self.meshes[i] for i in live]
        for key, index in self.mesh_of_key.items():
            if index is not None:
                self.mesh_of_key[key] = remap[index]
        self.instances = [dataclasses.replace(inst, mesh=remap[inst.mesh]) for inst in self.instances]

    def _placements(self):
        """Everything the walk produced, comparable between syncs."""
        instances = tuple((inst.mesh, np.asarray(inst.matrix).tobytes(), tuple(inst.materials),
                           inst.visible_camera, inst.visible_diffuse, inst.visible_glossy,
                           inst.visible_transmission, inst.visible_shadow)
                          for inst in self.instances)
        points = tuple((hash(np.asarray(c.positions).tobytes()), hash(np.asarray(c.radii).tobytes()),
                        np.asarray(c.matrix).tobytes(), tuple(c.materials)) for c in self.points)
        return instances, points, repr(self.lights)

    def _refresh_material(self, material):
        key = material.as_pointer()
        index = self.materials.index_of.get(key)
        if index is None:
            return  # not used yet: translated when an object needs it
        translated, _ = material_export.translate(material)
        self.materials.materials[index] = translated
        STATS['material_exports'] += 1
        self.version += 1

    def _refresh_all_materials(self):
        self.materials = material_export.MaterialTable()
        self.version += 1

    def _world_changed(self, depsgraph):
        world = depsgraph.scene.world
        return (world.as_pointer() if world else 0) != self._world_key

    def _export_world(self, depsgraph):
        world = depsgraph.scene.world
        self._world_key = world.as_pointer() if world else 0
        self.world, _ = world_export.world_from_blender(world)
        STATS['world_exports'] += 1
        self.version += 1

    def scene(self, camera):
        """An engine Scene with only the meshes in use (indices remapped)."""
        used = sorted({inst.mesh for inst in self.instances})
        remap = {old: new for new, old in enumerate(used)}
        instances = [dataclasses.replace(inst, mesh=remap[inst.mesh]) for inst in self.instances]
        return backend.engine().Scene(
            meshes=[self.meshes[i] for i in used], instances=instances,
            materials=list(self.materials.materials), lights=list(self.lights),
            world=self.world, camera=camera, points=list(self.points))


def _geometry_keys(obj):
    keys = {('object', obj.name_full)}
    if obj.data is not None:
        keys.add(obj.data.as_pointer())
    return keys


# -- the view's camera ---------------------------------------------------------

def viewport_camera(context, depsgraph, pixel_size=1):
    """engine.scene.Camera for the region (perspective, orthographic or the
    camera view), at the region's size divided by ``pixel_size``.

    The frustum is read off the region's projection matrix, so the camera view
    (with its zoom, offset and the area outside the frame) comes out exactly
    as Blender draws it.
    """
    region, rv3d = context.region, context.region_data
    width = max(1, region.width // pixel_size)
    height = max(1, region.height // pixel_size)
    window = np.array(rv3d.window_matrix, dtype=np.float64)
    to_world = np.linalg.inv(np.array(rv3d.view_matrix, dtype=np.float64))
    to_world[:3, :3] /= np.linalg.norm(to_world[:3, :3], axis=0)
    base = {}
    camera_obj = getattr(context.space_data, 'camera', None) or depsgraph.scene.camera
    if rv3d.view_perspective == 'CAMERA' and camera_obj is not None and camera_obj.type == 'CAMERA':
        base = _depth_of_field(camera_obj.evaluated_get(depsgraph), depsgraph.scene.render)
    fields = frustum(window, to_world)
    return backend.engine().Camera(
        resolution=(width, height), sensor_width=36.0, sensor_height=36.0 * height / width,
        sensor_fit='HORIZONTAL', **fields, **base)


def frustum(window, to_world):
    """Camera fields (kind, lens or ortho scale, shift, clipping, matrix) of a
    Blender projection matrix, horizontal sensor fit on a 36 mm sensor."""
    p = window
    if p[3, 3] == 0.0:  # perspective
        near = p[2, 3] / (p[2, 2] - 1.0)
        far = p[2, 3] / (p[2, 2] + 1.0)
        return dict(kind='PERSP', lens=36.0 * p[0, 0] / 2.0, shift_x=p[0, 2] / 2.0,
                    shift_y=p[1, 2] * p[0, 0] / (2.0 * p[1, 1]),
                    clip_start=float(near), clip_end=float(far), matrix=to_world)
    near = (p[2, 3] + 1.0) / p[2, 2]
    far = (p[2, 3] - 1.0) / p[2, 2]
    matrix = to_world.copy()
    if near < 0.0:
        # User orthographic views clip behind the view point; move the
        # camera back instead of using a negative clip start.
        matrix[:3, 3] += matrix[:3, 2] * -near
        near, far = 0.0, far - near
    return dict(kind='ORTHO', ortho_scale=2.0 / p[0, 0], shift_x=-p[0, 3] / 2.0,
                shift_y=-p[1, 3] * p[0, 0] / (2.0 * p[1, 1]),
                clip_start=float(near), clip_end=float(far), matrix=matrix)


def _depth_of_field(camera_obj, render):
    camera, _ = camera_export.camera_from_blender(camera_obj, render)
    return dict(focus_distance=camera.focus_distance, fstop=camera.fstop,
                aperture_radius=camera.aperture_radius)


def view_key(context):
    """What a redraw compares to know the view moved: projection, view, size."""
    rv3d = context.region_data
    return (tuple(np.round(np.array(rv3d.window_matrix).ravel(), 7)),
            tuple(np.round(np.array(rv3d.view_matrix).ravel(), 7)))


# -- the render thread ---------------------------------------------------------

@dataclasses.dataclass
class Job:
    scene: object               # engine.scene.Scene, camera at full viewport resolution
    settings: object            # engine.scene.RenderSettings, samples = viewport samples
    denoise: bool = False
    changed_at: float = 0.0     # perf_counter of the change that started it


def levels(width, height, budget=FIRST_PASS_PIXELS):
    """Resolution dividers, coarse to fine: the first pass has at most
    ``budget`` pixels, each next one twice the resolution, the last 1."""
    divider = 1
    while (width // divider) * (height // divider) > budget and divider < 64:
        divider *= 2
    out = []
    while divider > 1:
        out.append(divider)
        divider //= 2
    return out + [1]


class RenderThread:
    """Renders Jobs one after the other; a new job stops the current one."""

    def __init__(self):
        self.cond = threading.Condition()
        self.job = None
        self.generation = 0
        self.closed = False
        self.image = None           # latest (H, W, 4) float32, row 0 at the top
        self.image_generation = 0   # bumps with every published image
        self.image_job = 0          # the job (generation) that made it
        self.finished_job = 0       # the last job that ran to its end
        self.samples = 0
        self.status = ''
        self.error = None
        self.busy = False
        self.thread = threading.Thread(target=self._loop, name='ember-viewport', daemon=True)
        self.thread.start()

    def submit(self, job):
        """Start a job (stopping the current one); returns its number."""
        with self.cond:
            self.generation += 1
            self.job = job
            self.cond.notify_all()
        STATS['restarts'] += 1
        return self.generation

    def stop(self):
        """Stop rendering (pause); the last image stays."""
        with self.cond:
            self.generation += 1
            self.job = None
            self.cond.notify_all()

    def close(self):
        with self.cond:
            self.closed = True
            self.generation += 1
            self.cond.notify_all()

    def _loop(self):
        while True:
            with self.cond:
                while not self.closed and self.job is None:
                    self.cond.wait()
                if self.closed:
                    return
                job, generation = self.job, self.generation
                self.job = None
                self.busy = True
            try:
                self._run(job, generation)
            except Exception as err:  # noqa: BLE001 - shown in the viewport, never lost
                message = str(err).strip() or type(err).__name__
                self.error = message
                STATS['errors'].append(traceback.format_exc())
            finally:
                self.busy = False

    def _stale(self, generation):
        return self.closed or self.generation != generation

    def _run(self, job, generation):
        backend.require_ray_tracer()
        render = backend.engine().render
        self.error = None
        camera = job.scene.camera
        width, height = camera.resolution
        first = True
        for divider in levels(width, height):
            small = dataclasses.replace(camera, resolution=(max(1, width // divider),
                                                            max(1, height // divider)))
            samples = 1 if divider > 1 else job.settings.samples
            # The denoiser's guides only where it runs: the last, full-size level.
            aovs = ("normal", "albedo") if job.denoise and divider == 1 else ()
            settings = dataclasses.replace(job.settings, samples=samples, samples_per_pass=1,
                                           time_limit=0.0, aovs=aovs)
            progress = _ThreadProgress(self, generation, divider, samples)
            result = render(dataclasses.replace(job.scene, camera=small), settings, progress)
            if self._stale(generation):
                return
            if first:
                STATS['first_image_seconds'].append(time.perf_counter() - job.changed_at)
                first = False
        if job.denoise and result.samples > 0:
            self._denoise(result, generation)
        self.status = f"Sample {result.samples}/{job.settings.samples}" + (" (denoised)" if job.denoise else "")
        self.finished_job = generation

    def _denoise(self, result, generation):
        self.status = "Denoising"
        rgb = denoise.denoise(result.image[..., :3], result.albedo, result.normal, quality='fast')
        if not self._stale(generation):
            image = result.image.copy()
            image[..., :3] = rgb
            self.publish(image, generation)

    def publish(self, image, generation):
        with self.cond:
            if self.generation != generation:
                return
            self.image = image
            self.image_job = generation
            self.image_generation += 1


class _ThreadProgress:
    """The engine's progress callback inside the render thread."""

    def __init__(self, thread, generation, divider, samples_total):
        self.thread = thread
        self.generation = generation
        self.divider = divider
        self.samples_total = samples_total

    def on_pass(self, image, samples_done, stats):
        self.thread.publish(image, self.generation)
        self.thread.samples = samples_done
        if self.divider > 1:
            self.thread.status = f"Rendering at 1/{self.divider} resolution"
        else:
            self.thread.status = f"Sample {samples_done}/{self.samples_total}"

    def on_status(self, text, fraction):
        self.thread.status = text      # "Compiling kernels (n/N)" before the first image

    def should_stop(self):
        return self.thread._stale(self.generation)


# -- drawing -----------------------------------------------------------------------

def display_pixels(image):
    """RGBA float32, bottom row first, flat, safe for a half-float texture
    (NaN -> 0, overflow clamped to the largest half)."""
    flipped = np.ascontiguousarray(image[::-1], dtype=np.float32)
    np.nan_to_num(flipped, copy=False, nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)
    np.clip(flipped, -HALF_MAX, HALF_MAX, out=flipped)
    return flipped.reshape(-1)


class DrawData:
    """The latest image as a GPU texture, drawn over the whole region."""

    def __init__(self, image):
        import gpu  # lazy: only where a window draws, never in background renders
        height, width = image.shape[:2]
        pixels = display_pixels(image)
        buffer = gpu.types.Buffer('FLOAT', pixels.size, pixels)
        self.texture = gpu.types.GPUTexture((width, height), format='RGBA16F', data=buffer)

    def draw(self, width, height):
        from gpu_extras.presets import draw_texture_2d  # lazy: as gpu above
        draw_texture_2d(self.texture, (0, 0), width, height)


# -- the session: what the RenderEngine delegates to ---------------------------

class ViewportSession:
    def __init__(self, engine):
        self.engine = engine
        self.cache = SceneCache()
        self.thread = RenderThread()
        self.synced = False
        self.scene_version = 0
        self.started = None          # (scene_version, view key, size, settings) of the running job
        self.pending_size = None     # (size, time first seen) while a resize settles
        self.settings = None
        self.denoise = False
        self.paused = False
        self.changed_at = time.perf_counter()
        self.draw_data = None
        self.drawn_generation = -1
        self.timer = None
        self.closed = False
        self.job_number = None
        self.job_changed_at = None   # the change behind the running job, until its first draw
        SESSIONS.add(self)

    # main thread only ---------------------------------------------------------
    def view_update(self, context, depsgraph):
        if self.cache.sync(depsgraph, first=not self.synced):
            self.scene_version += 1
            self.changed_at = time.perf_counter()
        self.synced = True
        self._read_settings(depsgraph.scene)
        self._ensure_timer()

    def _read_settings(self, scene):
        """Render settings, pause and denoise: read at every update and draw
        (a setting changed in a panel need not come with a depsgraph update)."""
        settings = scene_export.render_settings(scene, is_preview=False)
        self.settings = dataclasses.replace(
            settings, samples=scene.ember.viewport_samples, time_limit=0.0,
            aovs=("normal", "albedo") if scene.ember.use_preview_denoising else ())
        self.denoise = scene.ember.use_preview_denoising
        self.paused = scene.ember.preview_pause

    def view_draw(self, context, depsgraph):
        if not self.synced:
            return
        self._read_settings(depsgraph.scene)
        region = context.region
        size = (region.width, region.height)
        self._maybe_restart(context, depsgraph, size)
        image_generation = self.thread.image_generation
        if self.thread.image is not None and image_generation != self.drawn_generation:
            self.draw_data = DrawData(self.thread.image)
            self.drawn_generation = image_generation
            if self.job_changed_at is not None and self.thread.image_job == self.job_number:
                STATS['first_draw_seconds'].append(time.perf_counter() - self.job_changed_at)
                self.job_changed_at = None
        if self.draw_data is not None:
            import gpu  # lazy: as in DrawData
            gpu.state.blend_set('ALPHA_PREMULT')
            self.engine.bind_display_space_shader(depsgraph.scene)
            self.draw_data.draw(*size)
            self.engine.unbind_display_space_shader()
            gpu.state.blend_set('NONE')
        self._show_status()

    def _maybe_restart(self, context, depsgraph, size):
        """Start a job when the scene, the view, the settings or (once it
        holds still) the region size changed since the running one."""
        key = view_key(context)
        inputs = (self.scene_version, key, self.settings, self.denoise, self.paused)
        started = self.started
        now = time.perf_counter()
        if started is not None and started[1] != size:
            # A resize: wait until the size holds still (the old image stretches meanwhile).
            if self.pending_size is None or self.pending_size[0] != size:
                self.pending_size = (size, now)
                self.changed_at = now
                return
            if now - self.pending_size[1] < RESIZE_DELAY:
                return
        elif started is not None and started[0] == inputs:
            return
        elif started is not None and started[0][0] == self.scene_version and started[0][1] != key:
            self.changed_at = now  # the view moved: that is the change
        self.started = (inputs, size)
        self.pending_size = None
        if self.paused:
            self.thread.stop()
            return
        pixel_size = max(1, int(self.engine.get_preview_pixel_size(depsgraph.scene)))
        camera = viewport_camera(context, depsgraph, pixel_size)
        scene = self.cache.scene(camera)
        self.job_number = self.thread.submit(Job(scene, self.settings, self.denoise, self.changed_at))
        self.job_changed_at = self.changed_at

    def _show_status(self):
        thread = self.thread
        if thread.error:
            self.engine.update_stats("", "Ember: " + thread.error)
        elif self.paused:
            self.engine.update_stats("", "Ember: paused")
        else:
            self.engine.update_stats("", "Ember: " + (thread.status or "starting"))

    def _ensure_timer(self):
        if self.timer is not None:
            return

        def tick():
            if self.closed:
                return None
            try:
                self.engine.is_preview  # noqa: B018 - raises once Blender freed the engine
                if (self.thread.image_generation != self.drawn_generation
                        or self.pending_size is not None or self.thread.busy):
                    self.engine.tag_redraw()
            except ReferenceError:  # Blender freed the engine (shading changed)
                self.close()
                return None
            return REDRAW_INTERVAL
        self.timer = tick
        bpy.app.timers.register(tick, first_interval=REDRAW_INTERVAL)

    def close(self):
        if not self.closed:
            self.closed = True
            self.thread.close()
