"""Per-pixel accumulation of samples.

A batch of paths fills a Tile (float64 sums over a contiguous range of
pixels); the Film keeps, per pixel, the sample count, the mean radiance and
the sum of squared deviations from it (M2), combined tile by tile with
Chan's parallel formula.  Means and M2 are float32: no cancellation (M2 is
never a difference of large sums), half the memory of float64 sums, and two
films merge exactly as the statistics of all their samples (farm shards).

Adaptive sampling reads a second estimate of each pixel built from half of
its samples (Cycles' "aux" buffer, class-A samples); it is kept only when
adaptive sampling is on.  First-hit AOVs (depth, normal, albedo) are kept
only when asked for.

The M2 of each pixel's channel sum R + G + B is kept only when asked for
(``sum_variance``: the tests' region totals).  The channels of one path are
strongly correlated (a grey path adds the same to all three), so the
variance of a sum over channels is not the sum of the channel variances: up
to three times more.  It is a second accumulator, not a derived number.
"""
import threading

import numpy as np

from . import passes as extra_passes
from .sampler import is_class_a

MAX_RADIANCE = 1e30   # engine.validate.MAX_MAGNITUDE

AOV_CHANNELS = {"depth": 1, "normal": 3, "albedo": 3}
STATE_VERSION = 1


class Tile:
    """float64 sums for the pixels [lo, hi), filled by one batch."""

    def __init__(self, lo, hi, aovs=tuple(AOV_CHANNELS), aux=False, passes=(), guide=None, sum_variance=False,
                 path_guide=None, first=0):
        self.lo, self.hi = lo, hi
        # Path guiding (integrator/path_guide.py): the guide this batch
        # samples (None: none yet) and, while it trains, the records it makes.
        self.path_guide = None if path_guide is None else path_guide.sampled
        self.path_records = None if path_guide is None else path_guide.records_for(first)
        self.path_sums = []
        # Volume scattering probability guiding (integrator/volume_guide.py):
        # the film's filtered view this batch reads, and the sums it adds.
        self.guide = None if guide is None else guide.view
        self.guide_sums = None
        self.extra = extra_passes.Sums(passes, lo, hi) if passes else None
        n = hi - lo
        self.rgb = np.zeros((n, 3))
        self.rgb2 = np.zeros((n, 3))
        self.sum2 = np.zeros(n) if sum_variance else None   # squares of R + G + B
        self.alpha = np.zeros(n)
        self.holdout = np.zeros(n)
        self.count = np.zeros(n)
        self.aovs = {name: np.zeros((n, AOV_CHANNELS[name])) for name in aovs}
        self.aux = np.zeros((n, 3)) if aux else None
        self.catcher = None
        self._pending = []

    def add_guide(self, pix, guide, L):
        """Finished paths' guide sums (their Paths.guide rows)."""
        from .integrator import volume_guide
        part = volume_guide.sums(self.lo, self.hi, pix, guide, L)
        if self.guide_sums is None:
            self.guide_sums = part
        else:
            for a, b in zip(self.guide_sums, part):
                a += b

    def _bin(self, pix, w):
        return np.bincount(pix - self.lo, weights=w, minlength=self.hi - self.lo)

    def add_radiance(self, pix, L, sample=None):
        """Queue finished paths; ``flush`` bins them all at once.  ``sample``
        (the paths' sample indices) feeds adaptive sampling's half buffer."""
        # A path whose weight chain overflowed past the largest radiance Ember
        # renders (textured weights times textured emission) is held there,
        # as validation holds constants; NaN and inf stay visible to the checks.
        L = np.where(np.isfinite(L), np.clip(L, -MAX_RADIANCE, MAX_RADIANCE), L)
        self._pending.append((pix, L, sample))

    def _bin3(self, pix, values):
        idx = (pix[:, None] * 3 + np.arange(3)).ravel()
        n = 3 * (self.hi - self.lo)
        return np.bincount(idx, weights=values.ravel(), minlength=n).reshape(-1, 3)

    def flush(self):
        if self.path_records is not None and self.path_records.parts:
            self.path_sums.append(self.path_records.summed())
        if not self._pending:
            return
        pix = np.concatenate([p for p, _, _ in self._pending]) - self.lo
        L = np.concatenate([l for _, l, _ in self._pending])
        if self.aux is not None:
            sample = np.concatenate([s for _, _, s in self._pending])
            a = is_class_a(sample)
            self.aux += self._bin3(pix[a], L[a])
        self._pending = []
        self.rgb += self._bin3(pix, L)
        self.rgb2 += self._bin3(pix, L * L)
        if self.sum2 is not None:
            total = L.sum(axis=1)
            self.sum2 += np.bincount(pix, weights=total * total, minlength=self.hi - self.lo)

    # -- shadow catchers (engine/integrator/catcher.py) ------------------------

    def _catcher_sums(self):
        if getattr(self, "catcher", None) is None:
            n = self.hi - self.lo
            self.catcher = {"matte": np.zeros((n, 3)), "light": np.zeros((n, 3)), "split": np.zeros(n),
                            "background": np.zeros((n, 3))}
        return self.catcher

    def add_catcher(self, pix, L, flag):
        """Radiance of ended paths by their catcher flag: matte paths (0) to
        the matte, catcher paths (2) to the catcher's light."""
        sums = self._catcher_sums()
        for key, sel in (("matte", flag == 0), ("light", flag == 2)):
            if sel.any():
                sums[key] += self._bin3(pix[sel] - self.lo, L[sel])

    def add_split(self, pix, transparency, background=None):
        sums = self._catcher_sums()
        sums["split"] += self._bin(pix, transparency)
        if background is not None:
            sums["background"] += self._bin3(pix - self.lo, background)

    def add_background(self, pix, values):
        self._catcher_sums()["background"] += self._bin3(pix - self.lo, values)

    def add_holdout(self, pix, transparency):
        """Camera paths met holdouts: the film's alpha is uncovered by
        ``transparency`` (Cycles' film_write_holdout), transparent film or not."""
        self.holdout += self._bin(pix, transparency)

    def add_camera(self, pix, alpha, depth, normal, albedo):
        self.count += np.bincount(pix - self.lo, minlength=self.hi - self.lo)
        self.alpha += self._bin(pix, alpha)
        for name, values in (("depth", depth), ("normal", normal), ("albedo", albedo)):
            acc = self.aovs.get(name)
            if acc is None:
                continue
            values = values.reshape(len(pix), -1)
            for c in range(acc.shape[1]):
                acc[:, c] += self._bin(pix, values[:, c])


class Film:
    """Per-pixel sample statistics of a whole frame (row 0 at the top)."""

    def __init__(self, width, height, aovs=tuple(AOV_CHANNELS), adaptive=False, passes=(), crypto_levels=6,
                 guide=False, sum_variance=False, path_guide=None):
        unknown = set(aovs) - set(AOV_CHANNELS)
        if unknown:
            raise ValueError(f"unknown AOVs {sorted(unknown)}; known: {sorted(AOV_CHANNELS)}")
        self.width, self.height = width, height
        self.passes = tuple(passes)   # named extra passes, see the block at the end
        self.extra = extra_passes.Sums(self.passes, 0, width * height, crypto_levels) if self.passes else None
        n = width * height
        self.count = np.zeros(n, np.float32)
        self.mean = np.zeros((n, 3), np.float32)
        self.m2 = np.zeros((n, 3), np.float32)
        # M2 of R + G + B per pixel, only when asked (the module docstring).
        self.m2_sum = np.zeros(n, np.float32) if sum_variance else None
        self.alpha = np.zeros(n, np.float32)   # sum of coverage
        self.holdout = np.zeros(n, np.float32)   # sum of holdout transparency
        self.catcher = None                      # shadow catcher sums (Tile.add_catcher)
        self.combined_alpha = np.ones(n, np.float32)   # Combined's alpha at the last image()
        self.aovs = {name: np.zeros((n, AOV_CHANNELS[name]), np.float32) for name in aovs}
        # Adaptive sampling: sum of the class-A samples' radiance.
        self.aux = np.zeros((n, 3), np.float32) if adaptive else None
        # Camera rays in media guided by the samples so far (integrator/volume_guide.py).
        self.guide = None
        if guide:
            from .integrator.volume_guide import Guide
            self.guide = Guide(width, height)
        # Path guiding learned over the passes (integrator/path_guide.PathGuide).
        self.path_guide = path_guide
        self._lock = threading.Lock()

    # -- accumulation ------------------------------------------------------

    def new_tile(self, lo, hi, first=0):
        """A tile for pixels [lo, hi), of a pass from sample ``first``."""
        return Tile(lo, hi, tuple(self.aovs), self.aux is not None, self.passes, self.guide,
                    self.m2_sum is not None, self.path_guide, first)

    def merge(self, tile):
        tile.flush()
        s = slice(tile.lo, tile.hi)
        nb = tile.count
        with np.errstate(divide="ignore", invalid="ignore"):
            mean_b = np.where(nb[:, None] > 0, tile.rgb / nb[:, None], 0.0)
        m2_b = np.maximum(tile.rgb2 - tile.rgb * mean_b, 0.0)
        m2_sum_b = None
        if self.m2_sum is not None:
            m2_sum_b = np.maximum(tile.sum2 - tile.rgb.sum(axis=1) * mean_b.sum(axis=1), 0.0)
        with self._lock:
            self._combine(s, nb, mean_b, m2_b, m2_sum_b)
            self.alpha[s] += tile.alpha
            self.holdout[s] += tile.holdout
            if tile.catcher is not None:
                if self.catcher is None:
                    n = self.width * self.height
                    self.catcher = {k: np.zeros((n,) + v.shape[1:]) for k, v in tile.catcher.items()}
                for key, value in tile.catcher.items():
                    self.catcher[key][s] += value
            for name, acc in self.aovs.items():
                acc[s] += tile.aovs[name]
            if self.aux is not None:
                self.aux[s] += tile.aux
            if self.extra is not None and tile.extra is not None:
                self.extra.merge(tile.extra, tile.lo)
            if self.guide is not None and tile.guide_sums is not None:
                self.guide.merge(tile.lo, tile.guide_sums)
            if self.path_guide is not None:
                for part in tile.path_sums:
                    self.path_guide.merge(part)

    def _combine(self, s, nb, mean_b, m2_b, m2_sum_b=None):
        """Chan et al.'s pairwise update of (count, mean, M2), and of the
        channel sum's M2 where it is kept (dropped when the other side has
        none: it is then unknown)."""
        na = self.count[s].astype(np.float64)
        n = na + nb
        with np.errstate(divide="ignore", invalid="ignore"):
            fb = np.where(n > 0, nb / n, 0.0)[:, None]
        mean_a = self.mean[s].astype(np.float64)
        delta = mean_b - mean_a
        self.mean[s] = mean_a + delta * fb
        self.m2[s] += m2_b + delta * delta * (na[:, None] * fb)
        if self.m2_sum is not None and m2_sum_b is None:
            self.m2_sum = None
        elif self.m2_sum is not None:
            delta_sum = delta.sum(axis=1)
            self.m2_sum[s] += m2_sum_b + delta_sum * delta_sum * (na * fb[:, 0])
        self.count[s] = n

    # -- read-out ----------------------------------------------------------

    def _per_sample(self, arr):
        c = np.maximum(self.count, 1.0)
        return arr / (c if arr.ndim == 1 else c[:, None])

    def image(self, transparent=True, approximate_catcher=True):
        """(H, W, 4) float32 RGBA.  Alpha is the coverage with a transparent
        film, else 1, less what holdouts uncovered (as Cycles).  With a
        shadow catcher Combined is the matte: with the approximate shadow
        when ``approximate_catcher`` (Cycles: the Shadow Catcher pass off),
        in the alpha on a transparent film, over the background on an
        opaque one; without it (the pass holds the shadow) the matte alone."""
        out = np.empty((self.height * self.width, 4), np.float32)
        out[:, :3] = self.mean
        alpha = self._per_sample(self.alpha) if transparent else 1.0
        out[:, 3] = np.maximum(alpha - self._per_sample(self.holdout), 0.0)
        self.combined_alpha = out[:, 3].copy()     # the Shadow Catcher pass reads it
        if self.catcher is not None:
            out[:] = self._catcher_image(out, transparent, approximate_catcher)
        return out.reshape(self.height, self.width, 4)

    def shadow_catcher(self, alpha):
        """(N, 3) Cycles' Shadow Catcher pass: Combined without the matte
        over the catcher's own light (1 where no catcher was met), alpha-
        overed on white by Combined's alpha."""
        c = np.maximum(self.count.astype(np.float64), 1.0)
        combined = self.mean.astype(np.float64) * c[:, None]
        light = self.catcher["light"]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(light != 0, (combined - self.catcher["matte"]) / np.where(light != 0, light, 1.0), 1.0)
        ratio = np.where((self.catcher["split"] > 0)[:, None] | (light != 0), ratio, 1.0)
        a = np.asarray(alpha, np.float64)[:, None]
        return (1.0 - a) + a * ratio

    def _catcher_image(self, out, transparent, approximate):
        """Combined with a shadow catcher: the matte, with the approximate
        shadow (Cycles' shadow catcher matte with shadow) in the alpha or
        over the background, or alone."""
        c = np.maximum(self.count.astype(np.float64), 1.0)
        shadow = self.shadow_catcher(out[:, 3])
        matte = self.catcher["matte"] / c[:, None]
        # The matte's transparency: Combined's, and every split sample's throughput.
        matte_t = (1.0 - out[:, 3]) + self.catcher["split"] / c
        alpha = np.clip(1.0 - matte_t, 0.0, 1.0)
        alpha_matte = (1.0 - alpha) * (1.0 - np.clip(shadow.mean(axis=1), 0.0, 1.0)) + alpha
        image = np.empty_like(out, dtype=np.float64)
        if not approximate:
            image[:, :3], image[:, 3] = matte, alpha
        elif transparent:
            image[:, :3], image[:, 3] = matte, alpha_matte
        else:
            image[:, :3] = matte + self.catcher["background"] / c[:, None] * (1.0 - alpha_matte)[:, None]
            image[:, 3] = 1.0
        return image

    def variance(self):
        """(H, W, 3) float32 variance of each pixel's mean: the unbiased
        per-sample variance over the count (0 below two samples)."""
        c = self.count.astype(np.float64)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(c > 1, self.m2 / (c * (c - 1.0)), 0.0)
        # Squares of radiance near the float32 limit overflow float32: saturate.
        np.minimum(var, np.finfo(np.float32).max, out=var)
        return var.astype(np.float32).reshape(self.height, self.width, 3)

    def sum_variance(self):
        """(H, W) float32 variance of each pixel's mean of R + G + B (as
        ``variance``), or None when the film does not keep it."""
        if self.m2_sum is None:
            return None
        c = self.count.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(c > 1, self.m2_sum / (c * (c - 1.0)), 0.0)
        np.minimum(var, np.finfo(np.float32).max, out=var)
        return var.astype(np.float32).reshape(self.height, self.width)

    def aov(self, name):
        acc = self.aovs.get(name)
        if acc is None:
            return None
        arr = self._per_sample(acc)
        shape = (self.height, self.width) + ((arr.shape[1],) if arr.shape[1] > 1 else ())
        return arr.reshape(shape).astype(np.float32)

    def sample_count(self):
        return self.count.reshape(self.height, self.width).copy()

    # -- adaptive sampling (Cycles' convergence test) -------------------------

    def unconverged(self, threshold):
        """Pixels whose error estimate is above ``threshold`` (already
        scaled as Cycles scales its Noise Threshold), dilated by one pixel
        in x, then in y, so neighbours of noisy pixels keep sampling."""
        c = np.maximum(self.count, 1.0)[:, None]
        I = self.mean
        A = 2.0 * self.aux / c
        diff = np.abs(I - A).sum(axis=1)
        intensity = I.sum(axis=1)
        norm = np.where(intensity < 1.0, np.sqrt(np.maximum(intensity, 0.0)), intensity)
        noisy = (diff / (1e-4 + norm) >= threshold) | ~np.isfinite(diff)
        u = noisy.reshape(self.height, self.width)
        ux = u.copy()
        ux[:, 1:] |= u[:, :-1]
        ux[:, :-1] |= u[:, 1:]
        uy = ux.copy()
        uy[1:, :] |= ux[:-1, :]
        uy[:-1, :] |= ux[1:, :]
        return uy.ravel()

    # -- state for farm shards ---------------------------------------------

    def state(self):
        """The film's statistics as plain arrays (a farm shard)."""
        out = {"version": np.array(STATE_VERSION), "width": np.array(self.width),
               "height": np.array(self.height), "count": self.count, "mean": self.mean,
               "m2": self.m2, "alpha": self.alpha, "holdout": self.holdout}
        for name, acc in self.aovs.items():
            out["aov_" + name] = acc
        if self.aux is not None:
            out["aux"] = self.aux
        if self.m2_sum is not None:
            out["m2_sum"] = self.m2_sum
        return out

    @classmethod
    def from_state(cls, state):
        if int(state["version"]) != STATE_VERSION:
            raise ValueError(f"film state version {int(state['version'])}, expected {STATE_VERSION}")
        aovs = tuple(k[4:] for k in state if k.startswith("aov_"))
        film = cls(int(state["width"]), int(state["height"]), aovs, "aux" in state,
                   sum_variance="m2_sum" in state)
        film.merge_state(state)
        return film

    def merge_state(self, state):
        """Add another film's samples (same size, disjoint samples)."""
        if (int(state["width"]), int(state["height"])) != (self.width, self.height):
            raise ValueError("film states of different sizes cannot merge")
        n = self.width * self.height
        with self._lock:
            self._combine(slice(0, n), np.asarray(state["count"], np.float64),
                          np.asarray(state["mean"], np.float64), np.asarray(state["m2"], np.float64),
                          np.asarray(state["m2_sum"], np.float64) if "m2_sum" in state else None)
            self.alpha += state["alpha"]
            if "holdout" in state:     # shards written before holdouts have none
                self.holdout += state["holdout"]
            for name, acc in self.aovs.items():
                acc += state["aov_" + name]
            if self.aux is not None and "aux" in state:
                self.aux += state["aux"]


# ----------------------------------------------------------------------------
# Named extra passes (engine/passes.py): Tile.add_pass collects, Film.pass_images
# hands out the pictures.  Not part of state(): farm shards carry no passes yet.

def _tile_add_pass(self, name, pix, values, rank=None):
    """Add per-sample values of the named pass (ignored when not requested)."""
    if self.extra is not None:
        self.extra.add(name, pix, values, rank)


def _tile_wants(self, name):
    return self.extra is not None and self.extra.wants(name)


def _film_pass_images(self, config=None):
    """{name: (H, W, C) float32} for every requested pass."""
    if not self.passes:
        return {}
    return extra_passes.images(self.extra, self.count, self.width, self.height, self.passes,
                               film=self, config=config)


Tile.add_pass = _tile_add_pass
Tile.wants = _tile_wants
Film.pass_images = _film_pass_images
