"""Per-pixel sample statistics as (count, mean, M2) and their exact
combination (Chan, Golub and LeVeque 1979): merging the statistics of two
disjoint sets of samples gives those of their union, so shards can be
combined in any order and grouping.

Film states store raw sums (sum of x, sum of x^2, count); ``from_sums`` turns
them into (count, mean, M2), where M2 is the sum of squared deviations from
the mean (variance = M2 / (count - 1))."""
import numpy as np


def from_sums(count, s1, s2):
    count = np.asarray(count, np.float64)
    c = count.reshape(count.shape + (1,) * (np.ndim(s1) - count.ndim))
    mean = np.divide(s1, c, out=np.zeros(np.shape(s1)), where=c > 0)
    m2 = np.maximum(s2 - c * mean * mean, 0.0)
    return count, mean, m2


def of_samples(samples, axis=0):
    """(count, mean, M2) of an array of samples along ``axis`` (all at once)."""
    samples = np.asarray(samples, np.float64)
    n = samples.shape[axis]
    mean = samples.mean(axis=axis)
    m2 = ((samples - np.expand_dims(mean, axis)) ** 2).sum(axis=axis)
    return np.full(mean.shape[:1] if mean.ndim else (), float(n)), mean, m2


def combine(a, b):
    """(count, mean, M2) of the union of two disjoint sample sets."""
    na, mean_a, m2a = a
    nb, mean_b, m2b = b
    n = np.asarray(na, np.float64) + nb
    shape = n.shape + (1,) * (np.ndim(mean_a) - np.ndim(n))
    wa = np.divide(na, n, out=np.zeros_like(n), where=n > 0).reshape(shape)
    wb = np.divide(nb, n, out=np.zeros_like(n), where=n > 0).reshape(shape)
    delta = np.asarray(mean_b) - mean_a
    mean = mean_a + delta * wb
    m2 = m2a + m2b + delta * delta * (np.asarray(na, np.float64).reshape(shape) * wb)
    return n, mean, m2


def combine_all(parts):
    out = parts[0]
    for part in parts[1:]:
        out = combine(out, part)
    return out
