"""Emitters (see lightset.py): one module per light type, each registered in
registry.py; ``LightSet`` combines them.  Importing the package registers
every type.  The names below are those other modules and tests import."""
from . import area, mesh, point, sun, world  # noqa: F401  (registration, in any order)
from .area import AREA, AreaLights, _area_hit_rows, _area_light_sample, _area_sample_rows
from .common import (MAX_MAGNITUDE, MAX_SPHERICAL, MIN_SPHERICAL, Falloff, LightSample, selection_power,
                     smoothstep)
from .lightset import AUTO_ALL_LIGHTS, LightSet, resolve_selection
from .mesh import MAX_TREE_TRIANGLES, MESH, MeshLights
from .point import POINT, PointLights, _nearest_point, _point_sample
from .registry import REGISTRY, LightDef, definition_of, ordered, scene_lights_in_order, validate_light
from .sun import SUN, SunLights, _sun_sample
from .world import ENV, EnvironmentLight

# The point table's former private name (tests/engine/test_kernels.py).
_PointLights = PointLights
