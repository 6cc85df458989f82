"""Small statistics for comparing renders: Welch's t-test on pixel blocks.

No SciPy in Blender: the Student-t tail is integrated numerically (Simpson's
rule on the density), which is exact enough for thresholds at 1e-4.
"""
import math

import numpy as np


def t_pdf(x, dof):
    log_norm = math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2) - 0.5 * math.log(dof * math.pi)
    return np.exp(log_norm - (dof + 1) / 2 * np.log1p(x * x / dof))


def t_two_sided_p(t, dof, steps=4000):
    """P(|T| >= |t|) for Student's t with ``dof`` degrees of freedom."""
    t = abs(float(t))
    if not math.isfinite(t):
        return 0.0
    x = np.linspace(0.0, t, 2 * steps + 1)
    y = t_pdf(x, dof)
    h = t / (2 * steps)
    inner = h / 3 * (y[0] + y[-1] + 4 * y[1:-1:2].sum() + 2 * y[2:-1:2].sum())
    return max(0.0, 1.0 - 2.0 * inner)


def sidak_alpha(alpha, tests):
    """Per-test level that keeps the family-wise error at ``alpha``."""
    return 1.0 - (1.0 - alpha) ** (1.0 / tests)


def block_means(images, block):
    """(N, H, W, C) -> (N, H//block, W//block, C) means over block x block pixels."""
    n, h, w, c = images.shape
    h, w = h // block * block, w // block * block
    cropped = images[:, :h, :w]
    return cropped.reshape(n, h // block, block, w // block, block, c).mean(axis=(2, 4))


def welch(batches_a, batches_b):
    """Welch's t per element for two sets of independent batch means.

    batches_*: (N, ...) arrays, one row per independent batch (a seed, or a
    pass).  Returns (t, dof, mean_a, mean_b).
    """
    na, nb = len(batches_a), len(batches_b)
    mean_a, mean_b = batches_a.mean(axis=0), batches_b.mean(axis=0)
    var_a = batches_a.var(axis=0, ddof=1) / na
    var_b = batches_b.var(axis=0, ddof=1) / nb
    se2 = var_a + var_b
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (mean_a - mean_b) / np.sqrt(se2)
        dof = se2 ** 2 / (var_a ** 2 / (na - 1) + var_b ** 2 / (nb - 1))
    # Blocks where both renders are exactly constant (e.g. pure background)
    # agree if their means agree.
    constant = se2 == 0
    t = np.where(constant, np.where(mean_a == mean_b, 0.0, np.inf), t)
    dof = np.where(constant | ~np.isfinite(dof), max(min(na, nb) - 1, 1), dof)
    return t, dof, mean_a, mean_b


def failing_blocks(batches_a, batches_b, alpha=0.01):
    """Indices of blocks whose means differ at family-wise level ``alpha``.

    Returns (failures, details) with details a dict of summary numbers.
    """
    t, dof, mean_a, mean_b = welch(batches_a, batches_b)
    level = sidak_alpha(alpha, t.size)
    p = np.array([t_two_sided_p(ti, di) for ti, di in zip(t.ravel(), dof.ravel())]).reshape(t.shape)
    failures = np.argwhere(p < level)
    total_b = float(np.abs(mean_b).sum())
    details = {
        'blocks': int(t.size), 'level': level, 'max_abs_t': float(np.nanmax(np.abs(t))),
        'min_p': float(p.min()),
        'relative_mean_error': float(abs(mean_a.sum() - mean_b.sum()) / total_b) if total_b else 0.0,
        'relative_abs_error': float(np.abs(mean_a - mean_b).sum() / total_b) if total_b else 0.0,
    }
    return failures, details


def failing_single(single, batches, alpha=0.01):
    """Blocks where one independent render disagrees with a batched one.

    ``single`` is one render with the same sample count as the whole of
    ``batches`` (N independent per-pass block means), so both estimates have
    the variance var(batch)/N; their difference has twice that.
    """
    n = len(batches)
    mean = batches.mean(axis=0)
    var_mean = batches.var(axis=0, ddof=1) / n
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (single - mean) / np.sqrt(2.0 * var_mean)
    t = np.where(var_mean == 0, np.where(single == mean, 0.0, np.inf), t)
    level = sidak_alpha(alpha, t.size)
    p = np.array([t_two_sided_p(ti, n - 1) for ti in t.ravel()]).reshape(t.shape)
    return np.argwhere(p < level), {'blocks': int(t.size), 'max_abs_t': float(np.abs(t).max())}
