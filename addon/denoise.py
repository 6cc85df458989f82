"""Intel Open Image Denoise: ``denoise(rgb, albedo, normal) -> rgb``.

Two ways to run OIDN, chosen per process:

* in-process through its C API (ctypes), but only with the OIDN library that
  Blender itself ships (the bpy 4.2/5.0 modules and Blender 4.x/5.x builds
  carry ``lib/libOpenImageDenoise.so.2`` linked against Blender's own TBB);
* the ``oidnDenoise`` program of the bundled ``pyoidn`` wheel in a process of
  its own, on PFM files.  That is what runs inside Debian's Blender 3.4, which
  has no OIDN: loading the wheel's OIDN into that process binds it to the
  system's older libtbb.so.12 already loaded there, and it aborts
  (``munmap_chunk(): invalid pointer``).  A separate process keeps its own
  TBB through its RPATH.

Images are (H, W, 3) float32, row 0 at the top; albedo and normal are the
first-hit averages the renderer returns (not prefiltered; OIDN's default
model expects noisy auxiliary images).  Nothing here imports bpy, so the
render thread of the viewport may call it.
"""
import ctypes
import glob
import os
import subprocess
import sys
import tempfile
import threading

import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))
FORMAT_FLOAT3 = 3
DEVICE_CPU = 1


class DenoiseError(RuntimeError):
    """OIDN is missing or failed; the message is meant for the user."""


QUALITIES = {'default': 0, 'fast': 4, 'balanced': 5, 'high': 6}


def denoise(rgb, albedo=None, normal=None, quality='default'):
    """The denoised colour of an HDR image: (H, W, 3) float32.

    quality: OIDN's 'high' (its default), 'balanced' or 'fast' (the viewport).
    """
    if quality not in QUALITIES:
        raise ValueError(f"unknown denoising quality {quality!r}")
    color = _clean(rgb)
    aux = [_clean(a) if a is not None else None for a in (albedo, normal)]
    if aux[0] is None:
        aux[1] = None  # OIDN takes a normal only together with an albedo
    if color.size == 0:
        return color
    return backend().run(color, *aux, quality)


def _clean(image):
    """Contiguous float32 (H, W, 3) without NaN/Inf (OIDN propagates them)."""
    array = np.asarray(image, dtype=np.float32)[..., :3]
    return np.ascontiguousarray(np.nan_to_num(array, nan=0.0, posinf=0.0, neginf=0.0))


_backend = None
_backend_lock = threading.Lock()


def backend():
    """The backend for this process (found once)."""
    global _backend
    with _backend_lock:
        if _backend is None:
            library = blender_oidn_library()
            try:
                _backend = InProcess(library) if library else None
            except (OSError, AttributeError, DenoiseError):
                _backend = None  # an OIDN Ember cannot drive: use the program instead
            if _backend is None:
                _backend = Program(oidn_program())
        return _backend


def describe():
    """A short name of the backend in use (for logs and the README's claims)."""
    return backend().name


# -- in-process: Blender's own OIDN ------------------------------------------

def blender_oidn_library():
    """Path of the OIDN library Blender itself ships, or None."""
    for path in _mapped_libraries():
        if os.path.basename(path).startswith('libOpenImageDenoise.so'):
            return path
    bpy = sys.modules.get('bpy')
    if bpy is None:
        return None
    dirs = []
    if getattr(bpy, '__file__', None):
        dirs.append(os.path.join(os.path.dirname(bpy.__file__), 'lib'))   # the bpy module
    binary = getattr(getattr(bpy, 'app', None), 'binary_path', '') or ''
    if binary:
        dirs.append(os.path.join(os.path.dirname(binary), 'lib'))         # a Blender build
    for directory in dirs:
        found = sorted(glob.glob(os.path.join(directory, 'libOpenImageDenoise.so*')))
        if found:
            return found[0]
    return None


def _mapped_libraries():
    """Paths of the shared libraries loaded into this process."""
    try:
        with open('/proc/self/maps', encoding='utf-8', errors='replace') as maps:
            return sorted({line.split()[-1] for line in maps if '.so' in line and '/' in line})
    except OSError:
        return []


class InProcess:
    """OIDN's C API through ctypes (the GIL is released while it runs)."""

    def __init__(self, path):
        self.name = f"OIDN in-process ({os.path.basename(path)})"
        self.lib = lib = ctypes.CDLL(path)
        vp, cp, sz = ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t
        for name, args, result in (
                ('oidnNewDevice', [ctypes.c_int], vp), ('oidnCommitDevice', [vp], None),
                ('oidnNewFilter', [vp, cp], vp), ('oidnCommitFilter', [vp], None),
                ('oidnExecuteFilter', [vp], None), ('oidnReleaseFilter', [vp], None),
                ('oidnSetFilterBool', [vp, cp, ctypes.c_bool], None),
                ('oidnSetFilterInt', [vp, cp, ctypes.c_int], None),
                ('oidnSetSharedFilterImage', [vp, cp, vp, ctypes.c_int, sz, sz, sz, sz, sz], None),
                ('oidnGetDeviceError', [vp, ctypes.POINTER(cp)], ctypes.c_int)):
            function = getattr(lib, name)
            function.argtypes, function.restype = args, result
        self.lock = threading.Lock()
        self.device = lib.oidnNewDevice(DEVICE_CPU)
        lib.oidnCommitDevice(self.device)
        self._check()

    def _check(self):
        message = ctypes.c_char_p()
        if self.lib.oidnGetDeviceError(self.device, ctypes.byref(message)):
            text = message.value.decode(errors='replace') if message.value else 'unknown error'
            raise DenoiseError(f"Open Image Denoise: {text}")

    def run(self, color, albedo, normal, quality='default'):
        lib = self.lib
        height, width = color.shape[:2]
        output = np.empty_like(color)
        with self.lock:  # one filter at a time on the shared device
            filt = lib.oidnNewFilter(self.device, b'RT')
            try:
                images = [(b'color', color), (b'albedo', albedo), (b'normal', normal),
                          (b'output', output)]
                for name, image in images:
                    if image is not None:
                        lib.oidnSetSharedFilterImage(filt, name, image.ctypes.data, FORMAT_FLOAT3,
                                                     width, height, 0, 0, 0)
                lib.oidnSetFilterBool(filt, b'hdr', True)
                if quality != 'default':
                    lib.oidnSetFilterInt(filt, b'quality', QUALITIES[quality])
                lib.oidnCommitFilter(filt)
                lib.oidnExecuteFilter(filt)
                self._check()
            finally:
                lib.oidnReleaseFilter(filt)
        return output


# -- a process of its own: the bundled oidnDenoise ---------------------------

def oidn_program():
    """Path of ``oidnDenoise``: bundled in the add-on (vendor/oidn) or from an
    installed ``pyoidn``; raises DenoiseError when neither exists."""
    candidates = [os.path.join(_HERE, 'vendor', 'oidn', 'bin', 'oidnDenoise')]
    for entry in sys.path:
        candidates.append(os.path.join(entry, 'pyoidn', 'oidn', 'bin', 'oidnDenoise'))
    for path in candidates:
        if os.path.isfile(path):
            if not os.access(path, os.X_OK):
                os.chmod(path, 0o755)  # zips do not always keep the executable bit
            return path
    raise DenoiseError("Denoising needs Intel Open Image Denoise: install the Ember add-on zip "
                       "(it bundles OIDN) or `pip install pyoidn==2.5.1.0`")


class Program:
    def __init__(self, path):
        self.path = path
        self.name = f"OIDN program ({path})"

    def run(self, color, albedo, normal, quality='default'):
        with tempfile.TemporaryDirectory(prefix='ember_oidn_') as tmp:
            args = [self.path, '--hdr', _write_pfm(tmp, 'color', color)]
            if albedo is not None:
                args += ['--alb', _write_pfm(tmp, 'albedo', albedo)]
            if normal is not None:
                args += ['--nrm', _write_pfm(tmp, 'normal', normal)]
            out = os.path.join(tmp, 'output.pfm')
            args += ['-o', out, '-v', '0']
            if quality != 'default':
                args += ['-q', quality]
            done = subprocess.run(args, capture_output=True, text=True, timeout=600, check=False)
            if done.returncode != 0 or not os.path.isfile(out):
                detail = (done.stderr or done.stdout).strip().splitlines()[-1:] or [f"exit {done.returncode}"]
                raise DenoiseError(f"oidnDenoise failed: {detail[0]}")
            return read_pfm(out)


def _write_pfm(directory, name, image):
    """PFM: 'PF', size, negative scale for little endian, rows bottom first."""
    path = os.path.join(directory, name + '.pfm')
    height, width = image.shape[:2]
    with open(path, 'wb') as stream:
        stream.write(f"PF\n{width} {height}\n-1.0\n".encode())
        stream.write(np.ascontiguousarray(image[::-1], dtype='<f4').tobytes())
    return path


def read_pfm(path):
    with open(path, 'rb') as stream:
        kind = stream.readline().strip()
        width, height = (int(v) for v in stream.readline().split())
        scale = float(stream.readline())
        channels = 3 if kind == b'PF' else 1
        dtype = '<f4' if scale < 0 else '>f4'
        data = np.frombuffer(stream.read(), dtype=dtype, count=width * height * channels)
    image = data.reshape(height, width, channels)[::-1].astype(np.float32)
    return np.ascontiguousarray(image if channels == 3 else np.repeat(image, 3, axis=2))
