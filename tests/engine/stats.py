"""Statistical helpers shared by the engine tests."""
import math

import numpy as np


def sidak_z(alpha, n):
    """Two-sided |z| threshold so that n independent tests keep family-wise level alpha."""
    per_test = 1.0 - (1.0 - alpha) ** (1.0 / max(n, 1))
    return normal_quantile(1.0 - per_test / 2.0)


def normal_quantile(p):
    """Inverse standard normal CDF by bisection on erfc."""
    lo, hi = -40.0, 40.0
    x = 0.0
    for _ in range(200):  # bisection on erfc is plenty for a test threshold
        x = 0.5 * (lo + hi)
        if 0.5 * math.erfc(-x / math.sqrt(2.0)) < p:
            lo = x
        else:
            hi = x
    return x


def block_means(img, var, block):
    """Means of block x block pixel blocks and the variance of each block mean."""
    h, w = img.shape[:2]
    h2, w2 = h // block * block, w // block * block
    a = img[:h2, :w2].reshape(h2 // block, block, w2 // block, block, -1)
    v = var[:h2, :w2].reshape(h2 // block, block, w2 // block, block, -1)
    n = block * block
    return a.mean(axis=(1, 3)), v.sum(axis=(1, 3)) / (n * n)


def z_scores(a, va, b, vb):
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (a - b) / np.sqrt(va + vb)
    return np.where((va + vb) > 0, z, np.where(a == b, 0.0, np.inf))
