"""Build engine/data/thin_film_cmf.npz: the Fourier-transformed CIE 1931 XYZ
colour matching functions Cycles' thin-film Fresnel integrates against
(table_thin_film_cmf[512][6]: real X Y Z, imaginary X Y Z, over optical path
differences 0 to 60 um).  Like the sheen LTC fit it is data of the model,
read from Cycles' shader.tables:

    .venv/bin/python -m engine.data.build_thin_film --cycles-tables PATH/src/scene/shader.tables
"""
import argparse
import os
import re

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def read_cmf(path):
    with open(path, encoding="utf-8") as handle:
        text = handle.read()
    m = re.search(r"table_thin_film_cmf\[(\d+)\]\[(\d+)\]\s*=\s*\{(.*?)\n\};", text, re.S)
    if m is None:
        raise SystemExit(f"{path} has no table_thin_film_cmf")
    rows, cols = int(m.group(1)), int(m.group(2))
    values = np.array([float(v) for v in re.findall(r"[-+0-9.eE]+(?=f)", m.group(3))])
    if len(values) != rows * cols:
        raise SystemExit(f"table_thin_film_cmf: {len(values)} values, expected {rows * cols}")
    return values.reshape(rows, cols)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles-tables", required=True, help="Cycles' src/scene/shader.tables")
    parser.add_argument("-o", "--output", default=os.path.join(HERE, "thin_film_cmf.npz"))
    args = parser.parse_args()
    np.savez_compressed(args.output, cmf=read_cmf(args.cycles_tables).astype(np.float32))
    print("wrote", args.output)


if __name__ == "__main__":
    main()
