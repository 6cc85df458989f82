"""Build engine/data/hosek_xyz.npz: the coefficient tables of the Hosek-Wilkie
sky model (CIE XYZ version) that Cycles' Sky Texture 'HOSEK_WILKIE' uses.

    .venv/bin/python -m engine.data.build_hosek --header PATH/ArHosekSkyModelData_CIEXYZ.h
    .venv/bin/python -m engine.data.build_hosek --binary .venv/lib/python3.11/site-packages/bpy/__init__.so

Provenance: L. Hosek and A. Wilkie, "An Analytic Model for Full Spectral
Sky-Dome Radiance" (SIGGRAPH 2012), sample implementation version 1.4a
(February 2013, BSD 3-clause), file ArHosekSkyModelData_CIEXYZ.h ("Sep 9
pattern / Aug 23 mean dataset").  Blender carries the same file as
intern/sky/source/sky_model_data.h (3.x, 4.x) and sky_hosek_data.h (5.0).
The tables are data of the published model, not something to recompute.

Two sources give the same numbers:

* ``--header``: the C header, parsed (the arrays datasetXYZ1..3, 1080
  numbers each, and datasetXYZRad1..3, 120 each).
* ``--binary``: a Blender build (the bpy module's __init__.so or a blender
  executable), where the compiler keeps each static array as contiguous
  little-endian doubles: each is found by its first four published values
  (``STARTS``) and read whole.  Checked here to give identical tables in bpy
  5.0.1, bpy 4.2.23 and Debian's Blender 3.4.1.

Either way the result is checked against ``SPOT_VALUES`` (copied from the
header's text) before it is written.

Layout written (float64, the header's order reshaped):
  sky[channel X/Y/Z, albedo 0/1, turbidity 1..10, control point 0..5, parameter A..I]
  radiance[channel, albedo, turbidity, control point]
The 6 control points are the quintic Bezier (Bernstein) coefficients over
the solar elevation's cube root (elevation / (pi / 2))^(1/3).
"""
import argparse
import os
import re

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "hosek_xyz.npz")
SKY_SHAPE = (2, 10, 6, 9)
RADIANCE_SHAPE = (2, 10, 6)
# The first four numbers of each array in the published header.
STARTS = {
    "datasetXYZ1": (-1.117001e+000, -1.867262e-001, -1.113505e+001, 1.259865e+001),
    "datasetXYZ2": (-1.127942e+000, -1.905548e-001, -1.252356e+001, 1.375799e+001),
    "datasetXYZ3": (-1.310023e+000, -4.407658e-001, -3.640340e+001, 3.683292e+001),
    "datasetXYZRad1": (1.560219e+000, 1.417388e+000, 1.206927e+000, 1.091949e+001),
    "datasetXYZRad2": (1.632341e+000, 1.395230e+000, 1.375634e+000, 1.238193e+001),
    "datasetXYZRad3": (1.168084e+000, 2.156455e+000, -3.980314e+000, 1.989302e+001),
}
# (array, flat index, value) read from the header's text: the last entries
# and some in the middle, so a shifted or truncated array is caught.
SPOT_VALUES = [
    ("datasetXYZ1", 1079, 6.232887e-001), ("datasetXYZ1", 1076, -5.742810e-001),
    ("datasetXYZ1", 54, -1.113253e+000),          # albedo 0, turbidity 2, first
    ("datasetXYZ2", 54, -1.128399e+000), ("datasetXYZ2", 1076, -6.588777e-001),
    ("datasetXYZ2", 1079, 6.118645e-001), ("datasetXYZ3", 1079, 6.791814e-001),
    ("datasetXYZ3", 540, -1.279730e+000),         # albedo 1, turbidity 1, first
    ("datasetXYZ3", 593, 4.999327e-001),          # ... its last
    ("datasetXYZRad1", 60, 1.664273e+000), ("datasetXYZRad1", 119, 2.523432e+001),
    ("datasetXYZRad2", 60, 1.745162e+000), ("datasetXYZRad2", 119, 2.641780e+001),
    ("datasetXYZRad3", 60, 1.352858e+000), ("datasetXYZRad3", 119, 3.110255e+001),
]


def _length(name):
    return 120 if "Rad" in name else 1080


def from_header(path):
    text = open(path, encoding="utf-8", errors="replace").read()
    arrays = {}
    for name in STARTS:
        match = re.search(r"\b%s\[\]\s*=\s*\{(.*?)\};" % name, text, re.S)
        if match is None:
            raise SystemExit(f"{path}: no array {name}")
        body = re.sub(r"//[^\n]*", "", match.group(1))
        arrays[name] = np.array([float(v) for v in body.replace("\n", " ").split(",") if v.strip()])
    return arrays


def from_binary(path):
    data = open(path, "rb").read()
    arrays = {}
    for name, start in STARTS.items():
        pattern = np.array(start, "<f8").tobytes()
        at = data.find(pattern)
        if at < 0 or data.find(pattern, at + 1) >= 0:
            raise SystemExit(f"{path}: {name} found {data.count(pattern)} times, expected once")
        arrays[name] = np.frombuffer(data, "<f8", _length(name), at).copy()
    return arrays


def check(arrays):
    for name in STARTS:
        assert arrays[name].shape == (_length(name),), (name, arrays[name].shape)
        np.testing.assert_array_equal(arrays[name][:4], STARTS[name])
    for name, index, value in SPOT_VALUES:
        assert arrays[name][index] == value, (name, index, arrays[name][index], value)
        # Every number is one of the header's 7-digit decimals (a binary read
        # at a wrong offset or width would not be).
        values = arrays[name]
        assert all(float("%.6e" % v) == v for v in values), name


def tables(arrays):
    sky = np.stack([arrays[f"datasetXYZ{c}"].reshape(SKY_SHAPE) for c in (1, 2, 3)])
    radiance = np.stack([arrays[f"datasetXYZRad{c}"].reshape(RADIANCE_SHAPE) for c in (1, 2, 3)])
    return sky, radiance


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--header", help="ArHosekSkyModelData_CIEXYZ.h or Blender's sky_*_data.h")
    source.add_argument("--binary", help="a Blender build: bpy's __init__.so or a blender executable")
    parser.add_argument("--out", default=OUT)
    args = parser.parse_args(argv)
    arrays = from_header(args.header) if args.header else from_binary(args.binary)
    check(arrays)
    sky, radiance = tables(arrays)
    np.savez_compressed(args.out, sky=sky, radiance=radiance,
                        source=np.array(args.header or args.binary))
    print(f"wrote {args.out}: sky {sky.shape}, radiance {radiance.shape}, {os.path.getsize(args.out)} bytes")


if __name__ == "__main__":
    main()
