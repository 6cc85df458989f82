"""The statistics of the whole test suite (NumPy only: it also runs where
SciPy is missing).  See docs/testing.md.

* Distributions with exact tails: the normal (erfc), Student's t (the
  regularized incomplete beta function, Lentz's continued fraction, exact
  for any t and any degrees of freedom) and chi-square (the regularized
  incomplete gamma function).
* One false-alarm budget for the suite: ``SUITE_ALPHA`` is split evenly over
  at most ``FAMILIES`` families (Bonferroni between families), and inside a
  family over its tests (Sidak).  A family is one assertion about one
  quantity: a chi-square file, a block comparison, a whole-image mean test.
  ``family_level`` hands out a family's per-test level and counts the
  families used; tests/conftest.py reports the count and fails the session
  when it exceeds the budget.
* Power: ``detectable`` is the smallest true difference a two-sided test at
  a level detects with probability 1/2 (then the expected statistic sits
  exactly on the threshold); tests print it next to their result.
* Image comparisons: block means, Welch's t per block, and the mean over the
  whole image and over regions, for (a) two sets of independent batches,
  (b) one render with per-pixel variances and a reference with per-pixel
  variances (converged Cycles references, tests/data).
* Sums over channels: a pixel's R, G and B come from the same paths and are
  strongly correlated (a grey path adds the same to all three), so the
  variance of R + G + B is not the sum of the channel variances (up to 3x
  more).  A variance array with one channel more than its image carries the
  measured variance of the channel sum last (Ember's film with
  RenderSettings.sum_variance, the scatter of Cycles' seeds);
  ``sum_variance`` reads it, or bounds it where it was not measured.
"""
import math
import os

import numpy as np

SUITE_ALPHA = 0.01       # probability that a correct engine fails anywhere in the suite
FAMILIES = 560           # upper bound on the statistical families the suite runs
FAMILY_ALPHA = SUITE_ALPHA / FAMILIES
_families_used = []


# ----------------------------------------------------------------------------
# Budget

def family_level(name, tests=1):
    """Per-test level of one family of ``tests`` tests under the suite budget
    (and count the family)."""
    _families_used.append(name)
    return sidak(FAMILY_ALPHA, tests)


def families_used():
    return list(_families_used)


def sidak(alpha, tests):
    """Per-test level keeping the family-wise error rate of ``tests``
    independent tests at ``alpha``."""
    return -math.expm1(math.log1p(-alpha) / max(int(tests), 1))


# ----------------------------------------------------------------------------
# Normal

def normal_two_sided_p(z):
    return math.erfc(abs(float(z)) / math.sqrt(2.0))


def z_threshold(level):
    """|z| whose two-sided normal tail probability is ``level``."""
    lo, hi = 0.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if normal_two_sided_p(mid) > level:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def sidak_z(alpha, tests):
    """Two-sided |z| threshold of ``tests`` tests at family-wise ``alpha``."""
    return z_threshold(sidak(alpha, tests))


def z_scores(a, va, b, vb):
    """(a - b) / sqrt(va + vb); 0 where both are exact and equal, inf where
    exact and different."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (a - b) / np.sqrt(va + vb)
    return np.where((va + vb) > 0, z, np.where(a == b, 0.0, np.inf))


# ----------------------------------------------------------------------------
# Student's t through the incomplete beta function

def _beta_cf(a, b, x):
    """Continued fraction of I_x(a, b) (Numerical Recipes betacf, Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (tiny if abs(d) < tiny else d)
    h = d
    for m in range(1, 100000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (tiny if abs(d) < tiny else d)
        c = 1.0 + aa / c
        c = tiny if abs(c) < tiny else c
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (tiny if abs(d) < tiny else d)
        c = 1.0 + aa / c
        c = tiny if abs(c) < tiny else c
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            return h
    raise ArithmeticError(f"incomplete beta did not converge (a={a}, b={b}, x={x})")


def betainc(a, b, x):
    """Regularized incomplete beta function I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
                 + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_cf(b, a, 1.0 - x) / b


def t_two_sided_p(t, dof):
    """P(|T| >= |t|) for Student's t with ``dof`` degrees of freedom (exact;
    the normal tail for dof = inf)."""
    t = abs(float(t))
    if math.isnan(t):
        return 0.0
    if math.isinf(t):
        return 0.0
    if not math.isfinite(dof):
        return normal_two_sided_p(t)
    # I_x(dof/2, 1/2) with x = dof / (dof + t^2), computed without rounding
    # x to 1 for small t.
    x = dof / (dof + t * t)
    if x > 0.5:
        return 1.0 - betainc(0.5, 0.5 * dof, t * t / (dof + t * t))
    return betainc(0.5 * dof, 0.5, x)


def t_threshold(level, dof):
    """|t| whose two-sided tail probability is ``level``."""
    if not math.isfinite(dof):
        return z_threshold(level)
    lo, hi = 0.0, 1.0
    while t_two_sided_p(hi, dof) > level:
        lo, hi = hi, 2.0 * hi
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if t_two_sided_p(mid, dof) > level:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def t_p_values(t, dof):
    """Element-wise ``t_two_sided_p`` of arrays (dof broadcast)."""
    t, dof = np.broadcast_arrays(np.asarray(t, float), np.asarray(dof, float))
    return np.array([t_two_sided_p(ti, di) for ti, di in zip(t.ravel(), dof.ravel())]).reshape(t.shape)


# ----------------------------------------------------------------------------
# Chi-square through the incomplete gamma function

def _gamma_series(a, x):
    term = total = 1.0 / a
    ap = a
    for _ in range(100000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * 1e-16:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_cf(a, x):
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 100000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return math.exp(-x + a * math.log(x) - math.lgamma(a)) * h


def gamma_q(a, x):
    """Regularized upper incomplete gamma Q(a, x)."""
    if x <= 0.0:
        return 1.0
    if not math.isfinite(x):
        return 0.0
    if x < a + 1.0:
        return max(0.0, 1.0 - _gamma_series(a, x))
    return _gamma_cf(a, x)


def chi2_sf(stat, dof):
    """P(X >= stat) for X ~ chi-square with ``dof`` degrees of freedom."""
    return gamma_q(0.5 * dof, 0.5 * float(stat))


# ----------------------------------------------------------------------------
# Power

def detectable(se, level, dof=math.inf):
    """Smallest true difference that a two-sided test at ``level`` with
    standard error ``se`` detects with probability 1/2 (the far tail is
    negligible at these levels)."""
    return t_threshold(level, dof) * se


def power_line(name, relative_se, level, dof=math.inf):
    """One printable line: what the test resolves."""
    return (f"{name}: relative se {relative_se:.2e}, detects a relative bias of "
            f"{detectable(relative_se, level, dof):.2%} with probability 1/2 (level {level:.1e})")


def median_block_detects(limit, mean_b, var_a, var_b=0.0):
    """Power of a block z-test with threshold ``limit``: the relative bias
    the median lit block (its se over its mean ``mean_b``) shows with
    probability 1/2.  var_*: variances of the block means compared."""
    mean_b = np.abs(np.asarray(mean_b, float))
    lit = mean_b > 0
    if not lit.any():
        return 0.0
    se = np.sqrt(np.broadcast_to(np.asarray(var_a, float) + var_b, mean_b.shape))
    return float(limit * np.median(se[lit] / mean_b[lit]))


# ----------------------------------------------------------------------------
# Blocks, regions and batches

def block_means(images, block):
    """(N, H, W, C) -> (N, H//block, W//block, C) means over block x block pixels."""
    n, h, w, c = images.shape
    h, w = h // block * block, w // block * block
    cropped = images[:, :h, :w]
    return cropped.reshape(n, h // block, block, w // block, block, c).mean(axis=(2, 4))


def channel_variances(image, var):
    """The per-channel variances of ``var`` (without the sum's channel)."""
    return var[..., :image.shape[-1]]


def sum_variance(image, var):
    """(H, W) variance of each pixel's sum over its channels.  Measured when
    ``var`` has one channel more than ``image`` (its last); else bounded by
    Cauchy-Schwarz, (sum of the channel standard deviations)^2, exact for
    fully correlated channels and conservative otherwise (loses power).  The
    plain sum of the channel variances would be too small."""
    channels = image.shape[-1]
    var = np.asarray(var, float)
    if var.shape[-1] == channels + 1:
        return var[..., channels]
    if var.shape[-1] != channels:
        raise ValueError(f"variance has {var.shape[-1]} channels for an image of {channels}: "
                         f"expected {channels} (per channel) or {channels + 1} (and the channel sum)")
    return np.sqrt(np.maximum(var, 0.0)).sum(axis=-1) ** 2


def block_means_var(img, var, block):
    """One image (H, W, C) with per-pixel variances of its mean -> block
    means and the variances of the block means (pixels independent; a
    channel sum's variance in ``var`` is left out)."""
    var = channel_variances(img, var)
    h, w = img.shape[:2]
    h2, w2 = h // block * block, w // block * block
    a = img[:h2, :w2].reshape(h2 // block, block, w2 // block, block, -1)
    v = var[:h2, :w2].reshape(h2 // block, block, w2 // block, block, -1)
    n = block * block
    return a.mean(axis=(1, 3)), v.sum(axis=(1, 3)) / (n * n)


def regions(h, w, splits=2):
    """Pixel masks: the whole image, then a splits x splits grid of regions."""
    masks = [('image', np.ones((h, w), bool))]
    for i in range(splits):
        for j in range(splits):
            m = np.zeros((h, w), bool)
            m[i * h // splits:(i + 1) * h // splits, j * w // splits:(j + 1) * w // splits] = True
            masks.append((f'region {i},{j}', m))
    return masks


def welch(batches_a, batches_b):
    """Welch's t per element for two sets of independent batch means.

    batches_*: (N, ...) arrays, one row per independent batch (a seed, or a
    pass).  Returns (t, dof, mean_a, mean_b)."""
    na, nb = len(batches_a), len(batches_b)
    mean_a, mean_b = batches_a.mean(axis=0), batches_b.mean(axis=0)
    var_a = batches_a.var(axis=0, ddof=1) / na
    var_b = batches_b.var(axis=0, ddof=1) / nb
    return _welch_t(mean_a, var_a, na - 1, mean_b, var_b, nb - 1) + (mean_a, mean_b)


def _welch_t(mean_a, var_a, dof_a, mean_b, var_b, dof_b):
    mean_a, var_a, mean_b, var_b = (np.asarray(v, float) for v in (mean_a, var_a, mean_b, var_b))
    se2 = var_a + var_b
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (mean_a - mean_b) / np.sqrt(se2)
        dof = se2 ** 2 / (var_a ** 2 / dof_a + var_b ** 2 / dof_b)
    # Where both are exactly constant (pure background) they agree if equal.
    constant = se2 == 0
    t = np.where(constant, np.where(mean_a == mean_b, 0.0, np.inf), t)
    dof = np.where(constant | ~np.isfinite(dof), max(min(dof_a, dof_b), 1), dof)
    return t, dof


def failing_blocks(batches_a, batches_b, name='blocks'):
    """Blocks whose means differ, at the family level of the suite budget.

    Returns (failures, details) with details a dict of summary numbers."""
    t, dof, mean_a, mean_b = welch(batches_a, batches_b)
    level = family_level(name, t.size)
    p = t_p_values(t, dof)
    failures = np.argwhere(p < level)
    total_b = float(np.abs(mean_b).sum())
    details = {
        'blocks': int(t.size), 'level': level, 'max_abs_t': float(np.nanmax(np.abs(t))),
        'min_p': float(p.min()),
        'relative_mean_error': float(abs(mean_a.sum() - mean_b.sum()) / total_b) if total_b else 0.0,
        'relative_abs_error': float(np.abs(mean_a - mean_b).sum() / total_b) if total_b else 0.0,
    }
    return failures, details


def failing_single(single, batches, name='single vs batches'):
    """Blocks where one independent render disagrees with a batched one.

    ``single`` is one render with the same sample count as the whole of
    ``batches`` (N independent per-pass block means), so both estimates have
    the variance var(batch)/N; their difference has twice that."""
    n = len(batches)
    mean = batches.mean(axis=0)
    var_mean = batches.var(axis=0, ddof=1) / n
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (single - mean) / np.sqrt(2.0 * var_mean)
    t = np.where(var_mean == 0, np.where(single == mean, 0.0, np.inf), t)
    level = family_level(name, t.size)
    p = t_p_values(t, n - 1)
    return np.argwhere(p < level), {'blocks': int(t.size), 'max_abs_t': float(np.abs(t).max())}


def failing_blocks_var(image_a, var_a, dof_a, image_b, var_b, dof_b, block, name='blocks', float32_sums_b=1):
    """Blocks (and channels) where two images with per-pixel variances of
    their means differ (Welch's t), with the float32 rounding floor of
    ``region_mean_tests_var``.  Returns (failures, details); details holds
    the median block's detectable relative bias."""
    ma, va = block_means_var(image_a, channel_variances(image_a, var_a), block)
    mb, vb = block_means_var(image_b, channel_variances(image_b, var_b), block)
    va = va + (np.abs(ma) * 2.0 ** -24) ** 2 / 3.0
    vb = vb + (np.abs(mb) * max(float32_sums_b, 1) * 2.0 ** -24) ** 2 / 3.0
    t, dof = _welch_t(ma, va, dof_a, mb, vb, dof_b)
    level = family_level(name, t.size)
    p = t_p_values(t, dof)
    lit = np.abs(mb) > 0
    rel_se = np.sqrt(va + vb)[lit] / np.abs(mb[lit])
    median = float(np.median(rel_se)) if lit.any() else 0.0
    details = {'blocks': int(t.size), 'level': level, 'max_abs_t': float(np.nanmax(np.abs(t))),
               'median_block_detects': detectable(median, level, float(np.median(dof)))}
    return np.argwhere(p < level), details


class MeanTest:
    """Relative difference of two estimates of one total (a region's sum over
    pixels and channels), its standard error, t, dof and p."""

    def __init__(self, name, mean_a, var_a, dof_a, mean_b, var_b, dof_b, note=''):
        t, dof = _welch_t(mean_a, var_a, dof_a, mean_b, var_b, dof_b)
        self.note = note
        self.name, self.t, self.dof = name, float(t), float(dof)
        self.p = t_two_sided_p(self.t, self.dof)
        self.relative = (mean_a - mean_b) / mean_b if mean_b else 0.0
        self.relative_se = math.sqrt(var_a + var_b) / abs(mean_b) if mean_b else 0.0

    def __repr__(self):
        return (f"{self.name}: relative difference {self.relative:+.3%} +- {self.relative_se:.3%} "
                f"(t={self.t:.2f}, dof={self.dof:.0f}, p={self.p:.2g}){self.note}")


def region_mean_tests(batches_a, batches_b, name='region means', splits=2):
    """The whole image's and each region's total compared by Welch's t, from
    two sets of independent batch images (N, H, W, C).  One family; returns
    (tests, level)."""
    na, nb = len(batches_a), len(batches_b)
    tests = []
    for label, mask in regions(*batches_a.shape[1:3], splits):
        sa = batches_a[:, mask].sum(axis=(1, 2))
        sb = batches_b[:, mask].sum(axis=(1, 2))
        tests.append(MeanTest(label, sa.mean(), sa.var(ddof=1) / na, na - 1,
                              sb.mean(), sb.var(ddof=1) / nb, nb - 1))
    return tests, family_level(name, len(tests))


def region_mean_tests_var(image_a, var_a, dof_a, image_b, var_b, dof_b, name='region means', splits=2,
                          float32_sums_b=1):
    """As ``region_mean_tests`` for two images (H, W, C) with per-pixel
    variances of their means (pixels independent; the channels' covariance
    through ``sum_variance``: measured when var_* carry the sum's channel,
    else bounded).  ``float32_sums_b``: image b's pixels are float32 sums of
    that many samples (Cycles' film)."""
    tests = []
    sum_var_a, sum_var_b = sum_variance(image_a, var_a), sum_variance(image_b, var_b)
    channels_a, channels_b = channel_variances(image_a, var_a), channel_variances(image_b, var_b)
    how = '/'.join('measured' if v.shape[-1] > i.shape[-1] or i.shape[-1] == 1 else 'bound'
                   for i, v in ((image_a, var_a), (image_b, var_b)))
    for label, mask in regions(*image_a.shape[:2], splits):
        sa, sb = image_a[mask].sum(), image_b[mask].sum()
        va, vb = sum_var_a[mask].sum(), sum_var_b[mask].sum()
        independent = channels_a[mask].sum() + channels_b[mask].sum()
        note = f"; var of sums {how} {(va + vb) / independent:.2f}x the channels'" if independent > 0 else ''
        tests.append(MeanTest(label, sa, va + _rounding_var(image_a[mask], 1), dof_a,
                              sb, vb + _rounding_var(image_b[mask], float32_sums_b), dof_b, note))
    return tests, family_level(name, len(tests))


def _rounding_var(pixels, sums=1):
    """Images are float32: a noiseless region (a constant world) is only
    known to rounding.  A pixel accumulated as a float32 sum of ``sums``
    equal samples can be off by up to sums x 2^-24 relative, the same way in
    every pixel (systematic); as the variance of a uniform error on the
    region's sum."""
    bound = float(np.abs(pixels).sum()) * max(sums, 1) * 2.0 ** -24
    return bound * bound / 3.0


def report_mean_tests(title, tests, level):
    """Print the tests and their power (and append them to the file
    $EMBER_STATS_LOG if set: a record of a run under pytest-xdist, which
    swallows prints); returns those that fail."""
    lines = [f"{title} (per-test level {level:.1e}):"]
    lines += [f"  {test}; detects {detectable(test.relative_se, level, test.dof):.2%} with probability 1/2"
              for test in tests]
    print("\n" + "\n".join(lines))
    if os.environ.get("EMBER_STATS_LOG"):
        with open(os.environ["EMBER_STATS_LOG"], "a") as log:
            log.write("\n".join(lines) + "\n")
    return [test for test in tests if test.p < level]


def family_z(name, tests=1):
    """|z| threshold of one family of ``tests`` normal tests under the suite
    budget (counts the family)."""
    return z_threshold(family_level(name, tests))


def guided_pair_z(results, block):
    """(|z| of the kept block-channels, |z| of the whole-image channel means,
    the median block's and the image's relative se), guided (results[True]) vs not (results[False])."""
    blocks = {k: block_means_var(r.image[..., :3].astype(np.float64), r.variance[..., :3].astype(np.float64), block)
              for k, r in results.items()}
    keep = blocks[False][0] > 0.02 * blocks[False][0].max()
    z = np.abs(z_scores(*blocks[True], *blocks[False])[keep])
    ma, mb = (results[k].image[..., :3].astype(np.float64).sum(axis=(0, 1)) for k in (True, False))
    se = np.sqrt(sum(r.variance[..., :3].astype(np.float64).sum(axis=(0, 1)) for r in results.values()))
    rel = np.sqrt(blocks[True][1][keep] + blocks[False][1][keep]) / blocks[False][0][keep]
    return z, np.abs(ma - mb) / se, float(np.median(rel)), float((se / mb).max())
