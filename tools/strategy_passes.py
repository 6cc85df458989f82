"""Render Veach's plates with Ember's strategy passes and write them side by
side (docs/gallery/strategy_passes.png): Strategy Light, Strategy BSDF,
Strategy Light Unweighted, Strategy BSDF Unweighted, plus MIS Weight Light.

    PYTHONPATH=. python -P tools/strategy_passes.py [out.png] [--samples N]
"""
import argparse
import os
import sys

import numpy as np

from engine.imageio import write_image
from engine.render import render
from engine.scene import RenderSettings
from engine.testscenes import veach_four

PANELS = ("Strategy Light", "Strategy BSDF", "Strategy Light Unweighted", "Strategy BSDF Unweighted",
          "MIS Weight Light")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=os.path.join("docs", "gallery", "strategy_passes.png"))
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--width", type=int, default=240)
    args = parser.parse_args(argv)
    height = args.width * 3 // 4
    result = render(veach_four((args.width, height)),
                    RenderSettings(samples=args.samples, samples_per_pass=args.samples, seed=1,
                                   max_bounces=0, passes=PANELS))
    # One exposure for the four radiance panels: the 99th percentile of the
    # MIS image maps to 1 (the small lights' highlights clip, as in Veach's).
    mis = result.passes["Strategy Light"] + result.passes["Strategy BSDF"]
    scale = 1.0 / max(float(np.percentile(mis[mis > 0], 99)), 1e-6) if (mis > 0).any() else 1.0
    tiles = []
    for name in PANELS:
        img = result.passes[name] * (1.0 if name == "MIS Weight Light" else scale)
        rgb = np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img
        tiles.append(np.pad(rgb, ((0, 0), (0, 4), (0, 0)), constant_values=1.0))
    strip = np.concatenate(tiles, axis=1)[:, :-4]
    alpha = np.ones(strip.shape[:2] + (1,), np.float32)
    write_image(args.out, np.concatenate([strip, alpha], axis=2))
    print(f"wrote {args.out}: {' | '.join(PANELS)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
