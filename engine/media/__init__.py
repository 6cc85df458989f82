"""Participating media: homogeneous volumes inside closed meshes, as Cycles
renders them (kernel/integrator/shade_volume.h, volume_stack.h).

* ``table``: the media of a scene as plain arrays (one row per material with
  a Volume, a zero row for "none") and the per-path volume stack: the media a
  path is in, entered at front faces and left at back faces of their meshes.
* ``phase``: the phase functions of Volume Scatter (Henyey-Greenstein,
  Rayleigh, Draine, Fournier-Forand, Mie as HG + Draine), evaluation and
  sampling; a medium's is a mixture of two lobes.
* ``field``, ``tracking``: heterogeneous media (textured coefficients, a
  majorant grid) and null-scattering tracking through them.
* ``voxels``: an object's dense voxel grids (a fluid domain's smoke and
  fire), read by name as attributes inside its medium.
* ``flight``: what a ray segment through the stack's media does: attenuation,
  emission, and a scattering distance sampled per colour channel chosen by
  the throughput-weighted albedo (Cycles' ``volume_sample_channel``), all
  channels combined by MIS; and the transmittance of shadow rays.

The integrator's stage is engine/integrator/volume.py.  A scene without a
volume has no MediumTable (Context.media is None) and never gets here.
"""
from .flight import FreeFlight, emission_integral, free_flight, light_factor, transmittance_factor
from .phase import hg_eval, hg_sample, phase_eval, phase_sample
from .table import STACK_SIZE, MediumTable, camera_media, open_meshes, open_volume_meshes, start_stack

__all__ = ["FreeFlight", "MediumTable", "STACK_SIZE", "camera_media", "emission_integral", "free_flight",
           "hg_eval", "hg_sample", "phase_eval", "phase_sample", "light_factor", "open_meshes",
           "open_volume_meshes", "start_stack", "transmittance_factor"]
