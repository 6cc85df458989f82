"""Finds the Ember renderer and its native dependencies.

The add-on runs in three layouts:

* from the repository (tests, command line): the renderer is the top-level
  package ``engine`` next to ``addon``;
* installed from the legacy zip: the add-on is the package ``ember`` with the
  renderer vendored as ``ember.vendor.engine`` and the wheels Blender lacks
  unpacked in ``ember/vendor/site``;
* installed as an extension (4.2+): ``bl_ext.<repo>.ember`` with the renderer
  vendored the same way and the wheels installed by Blender.

The vendored copy is named ``vendor.engine`` because ``engine.py`` in this
package is the RenderEngine.  Nothing is imported at add-on registration: a
missing wheel must not stop Blender from starting, only show an error when a
render starts.
"""
import functools
import importlib
import os
import re
import sys
import threading

_HERE = os.path.dirname(os.path.abspath(__file__))
_VENDOR = os.path.join(_HERE, 'vendor')
_SITE = os.path.join(_VENDOR, 'site')


def _add_bundled_site():
    """Make the wheels unpacked into the legacy zip importable."""
    if os.path.isdir(_SITE) and _SITE not in sys.path:
        sys.path.append(_SITE)


_IMPORT_LOCK = threading.RLock()
_EMBREEX_MODULES = ('embreex', 'embreex.rtcore_scene', 'embreex.mesh_construction')


def _import_embreex():
    """Import embreex so that it binds to its own Embree library.

    Blender 3.4 links its own libembree3 with global symbols; without
    RTLD_DEEPBIND embreex resolves against it and building a scene crashes.
    The flag is harmless in newer Blender and is restored right away
    (OpenImageIO must not be loaded with it).  Under a lock: Blender's window
    runs preview renders in job threads, and the dlopen flags are process-wide,
    so two first imports must not interleave.
    """
    if all(m in sys.modules for m in _EMBREEX_MODULES) or not hasattr(sys, 'setdlopenflags'):
        return
    with _IMPORT_LOCK:
        if all(m in sys.modules for m in _EMBREEX_MODULES):
            return
        old = sys.getdlopenflags()
        sys.setdlopenflags(os.RTLD_NOW | os.RTLD_DEEPBIND)
        try:
            for module in _EMBREEX_MODULES:
                importlib.import_module(module)
        finally:
            sys.setdlopenflags(old)


def _package_name():
    """The name of the renderer package in this layout."""
    if os.path.isfile(os.path.join(_VENDOR, 'engine', '__init__.py')):
        return __package__ + '.vendor.engine'
    return 'engine'


@functools.lru_cache(maxsize=None)
def engine():
    """The renderer package (vendored or not): the add-on uses only the names
    its ``__all__`` declares.  Imported on first use, never at registration,
    after embreex (with RTLD_DEEPBIND) where embreex is installed: exporting
    needs no ray tracer, rendering does (``require_ray_tracer``)."""
    with _IMPORT_LOCK:   # one thread imports the renderer, the others wait for it (previews)
        _add_bundled_site()
        try:
            _import_embreex()
        except ImportError:
            pass   # require_ray_tracer() says why, when a render starts
        return importlib.import_module(_package_name())


def require_ray_tracer():
    """Before a render: ImportError saying how to install embreex if it is missing."""
    engine()
    try:
        _import_embreex()
    except ImportError as err:
        bundled = _bundled_python()
        if bundled and bundled != sys.version_info[:2]:
            raise ImportError(
                f"this Ember add-on zip carries wheels for Python {'.'.join(map(str, bundled))}, and this "
                f"Blender runs Python {sys.version_info[0]}.{sys.version_info[1]} ({err}); install the Ember "
                "extension zip, which carries wheels for each") from err
        raise ImportError(
            f"Ember needs the 'embreex' package ({err}); install the Ember "
            "extension zip, or pip install embreex into Blender's Python") from err


def _bundled_python():
    """(major, minor) of the wheels unpacked into the legacy zip, or None."""
    if not os.path.isdir(_SITE):
        return None
    for folder, _, files in os.walk(os.path.join(_SITE, 'embreex')):
        for name in files:
            match = re.search(r'\.cpython-3(\d+)-', name)
            if match:
                return (3, int(match.group(1)))
    return None
