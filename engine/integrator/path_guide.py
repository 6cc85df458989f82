"""Path guiding of the BSDF sample at surface vertices (Mueller, Gross and
Novak 2017, "Practical Path Guiding for Efficient Light-Transport
Simulation"), learned over the render's own passes.

The guide is a spatial binary tree over the scene's bounds (each level
halves its node at the midpoint, axes x, y, z in turn) whose leaves each
hold a directional quadtree over the equal-area cylindrical map of the
sphere, (x, y) = ((cos theta + 1) / 2, phi / 2 pi) with theta, phi in world
space: a constant pdf on the square is a constant pdf on the sphere,
p(w) = p_square / 4 pi.  The quadtree is Mueller's: a node is split while
its share of the leaf's energy exceeds RHO, down to RES x RES cells; a
quadtree leaf spreads its energy evenly over its area.  It is stored
expanded to its RES x RES finest cells (density and CDF per spatial leaf),
so the pdf is one look-up and sampling one binary search.

At a vertex whose lobes all reflect smoothly (no delta, transmission,
transparent, subsurface, hair or portal lobe, no second bump normal: the
``eligible`` rows) and whose spatial leaf has learned a distribution, the
direction comes from the guide with probability alpha = the leaf's guide
fraction times the lobes' roughness (u[:, 0] < alpha picks, then is
rescaled for the lobe choice), else from the BSDF, and the sample counts
with the mixture pdf alpha p_guide + (1 - alpha) p_bsdf (one-sample MIS).
Light samples there weigh the BSDF side of their MIS by the same mixture,
and BSDF rays that meet a light carry it as their pdf: unbiased whatever
the guide and the fraction hold.  The look-up (eligibility, roughness,
leaf, alpha: _vertex_loop) and the mixture (_split_loop, _directions_loop,
the BSDF at the chosen rows, _weights_loop; NEE's _nee_loop) are compiled
passes, each with its NumPy form.

The guide fraction is learned per spatial leaf (in the spirit of Mueller
2019's learned BSDF-sampling fraction, not by its per-sample Adam steps,
which depend on the order of the samples): each guided record also adds,
for every candidate a_k of FRACTIONS, an estimate of the second moment
of what the path gathered past the vertex had the mixture used a_k,
y^2 q_old / q_k (y that radiance, so vertices weigh by their throughput
as the pixel's variance does), in fixed point per leaf; at the rebuild
each leaf takes the a_k of least moment (guided ones raised by
GUIDE_COST, their CPU), ALPHA where it has too few records.  Where the
BSDF and NEE already sample the light well (the Cornell box) the fraction
falls to 0: those leaves are not guided once training ends (while it
lasts, their records keep learning with probability 0), and training and
guiding end early (STOP_SHARE) when most guided records chose 0.

A guided direction's kind (diffuse or glossy, for ray visibility and
passes) is drawn as Cycles' guided samples take theirs (surface_shader_bsdf_guided_sample_closure_mis: the closure
picked in proportion to its unguided pdf there): visibility.ray_kind with
the BSDF's own pdf, not the mixture.

Training: each path keeps its last SLOTS guided vertices (Paths.guide_path:
the recording cell, the path's radiance then and its throughput after the
bounce times the mixture pdf); when a slot is reused or the path ends, the
radiance gathered since, over that throughput, is the incident radiance
along the sampled direction divided by its pdf (Mueller's record), here
times the cosine at the vertex (the guide then leans to the product the
BSDF's own sampling leaves out: measured 4-5 % less variance), added to
its spatial leaf's RES x RES cell.  Records are summed as fixed-point
integers (FIXED), so the sums, and the guide built from them, are the same
bit for bit however the passes are cut into batches and in whatever order
tiles merge.  The guide of a pass is built from the records of the passes
since the previous rebuild only (rebuilt when the samples have doubled, as
engine/render.py does for the volume guide); the spatial tree is refined
then, each leaf halved while its records exceed SPLIT_RECORDS sqrt(spp of
that iteration), and training stops at ``path_guiding_training_samples``.
A sample range of a farm builds its own guide (and fractions) from its
own passes.
"""
import numpy as np

from ..geometry import corner_bounds
from ..kernels import LoopKernel, helper
from ..lobes import registry as lobe_registry
from ..rows import take_arrays
from ..vec import to_local, to_world

RES = 32                   # finest quadtree cells per side of the square
BINS = RES * RES
LEVELS = 5                 # log2(RES)
RHO = 0.01                 # Mueller's quadtree subdivision threshold
ALPHA = 0.3                # guide fraction of a leaf that has learned none yet (0.5: variance +25 % at 64 px)
MIN_ALPHA = 0.02           # below this (narrow glossy lobes) the BSDF alone samples
# Guide fractions a leaf may learn (FRACTIONS[k] times the vertex's roughness):
# the one of least estimated second moment of the bounce's estimator.
FRACTIONS = np.array([0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.65, 0.8])
K = len(FRACTIONS)
MIN_MOMENTS = 256          # guided records a leaf needs before it learns its fraction
GUIDE_COST = 0.05          # a guided leaf's second moment counts this much more (its CPU)
YMAX = 2.0 ** 8            # largest normalized contribution whose square is summed
RMIN = 2.0 ** -8           # smallest q_k / q_old summed
# Training, and guiding, stop early when, at a rebuild once STOP_AFTER
# samples have trained, fewer than STOP_SHARE of the guided records lie in
# leaves that learned a fraction above 0: most vertices do best with the
# BSDF alone (direct light NEE samples well), and the few guided leaves
# would not pay their CPU (Cornell box: variance 1.03x, CPU 1.16x).
STOP_AFTER = 8               # (at 4 the interior's guide, from 2 spp of records, still chose 0 in most leaves)
STOP_SHARE = 0.5
SPLIT_RECORDS = 4000       # spatial threshold c (times sqrt(spp)); Mueller: 12000 at 1280 x 720
MAX_DEPTH = 24             # spatial tree levels (8 halvings per axis)
MAX_LEAVES = 4096          # spatial leaves (memory: 2 x 8 KB each, film-side histograms 8 KB)
MIN_RECORDS = 64           # records a leaf needs before it guides
FIXED = 2.0 ** 16          # fixed-point scale of the records' sums
VMAX = 2.0 ** 20           # largest record (radiance over pdf) summed
SLOTS = 3                  # guided vertices a path remembers
SLOT = 6                   # per slot: cell, L, scale, f x norm (-1: no moment), x, old fraction
COLUMNS = 1 + SLOT * SLOTS  # Paths.guide_path: vertices written, then SLOT columns per slot
FOUR_PI = 4.0 * np.pi


# ----------------------------------------------------------------------------
# compiled loops and their NumPy reference forms

def _leaf_loop(unit, child, out):
    for i in range(unit.shape[0]):
        out[i] = _leaf_at(child, unit[i, 0], unit[i, 1], unit[i, 2])


def _leaf_numpy(unit, child, out):
    p = np.array(unit, dtype=np.float64, copy=True)
    node = np.zeros(len(p), np.int64)
    depth = 0
    while True:
        inner = child[node] >= 0
        if not inner.any():
            break
        a = depth % 3
        c = 2.0 * p[:, a]
        step = c >= 1.0
        p[:, a] = np.where(inner, np.where(step, c - 1.0, c), p[:, a])
        node = np.where(inner, child[node] + step, node)
        depth += 1
    out[:] = -1 - child[node]


_leaf_kernel = LoopKernel(_leaf_loop, "void(float64[:, ::1], int32[::1], int32[::1])", _leaf_numpy)


@helper
def _sample_one(l, u, u2, cdf, density):
    """A direction (x, y, z) of leaf l's distribution by (u, u2), and its pdf."""
    lo = 0
    hi = BINS - 1
    while lo < hi:   # the first cell whose CDF exceeds u
        mid = (lo + hi) // 2
        if cdf[l, mid] > u:
            hi = mid
        else:
            lo = mid + 1
    while lo > 0 and density[l, lo] <= 0.0:   # never a cell of no mass (u at a rounded end)
        lo -= 1
    before = cdf[l, lo - 1] if lo > 0 else 0.0
    mass = cdf[l, lo] - before
    f = (u - before) / mass if mass > 0.0 else 0.5
    f = min(max(f, 0.0), 1.0 - 1e-12)
    ix = lo // RES
    iy = lo - ix * RES
    x = (ix + u2) / RES
    y = (iy + f) / RES
    cz = min(max(2.0 * x - 1.0, -1.0), 1.0)
    r = np.sqrt(max(0.0, 1.0 - cz * cz))
    phi = 2.0 * np.pi * y
    return r * np.cos(phi), r * np.sin(phi), cz, density[l, lo] / FOUR_PI


def _sample_loop(leaf, u1, u2, cdf, density, wi, pdf):
    for i in range(leaf.shape[0]):
        l = leaf[i]
        if l < 0:
            wi[i, 0] = 0.0
            wi[i, 1] = 0.0
            wi[i, 2] = 1.0
            pdf[i] = 0.0
            continue
        x, y, z, p = _sample_one(l, u1[i], u2[i], cdf, density)
        wi[i, 0] = x
        wi[i, 1] = y
        wi[i, 2] = z
        pdf[i] = p


def _sample_numpy(leaf, u1, u2, cdf, density, wi, pdf):
    n = len(leaf)
    ok = leaf >= 0
    l = np.where(ok, leaf, 0)
    cell = np.empty(n, np.int64)
    for s in range(0, n, 4096):   # (rows, BINS) comparisons a chunk at a time
        e = slice(s, s + 4096)
        cell[e] = np.minimum((cdf[l[e]] <= u1[e, None]).sum(axis=1), BINS - 1)
    for _ in range(BINS):   # back over cells of no mass (rare: a rounded end)
        empty = (cell > 0) & (density[l, cell] <= 0.0)
        if not empty.any():
            break
        cell = np.where(empty, cell - 1, cell)
    before = np.where(cell > 0, cdf[l, np.maximum(cell - 1, 0)], 0.0)
    mass = cdf[l, cell] - before
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(mass > 0, (u1 - before) / np.where(mass > 0, mass, 1.0), 0.5)
    f = np.clip(f, 0.0, 1.0 - 1e-12)
    ix, iy = cell // RES, cell % RES
    cz = np.clip(2.0 * (ix + u2) / RES - 1.0, -1.0, 1.0)
    r = np.sqrt(np.maximum(0.0, 1.0 - cz * cz))
    phi = 2.0 * np.pi * (iy + f) / RES
    wi[:] = np.where(ok[:, None], np.stack([r * np.cos(phi), r * np.sin(phi), cz], axis=1), [0.0, 0.0, 1.0])
    pdf[:] = np.where(ok, density[l, cell] / FOUR_PI, 0.0)


_sample_kernel = LoopKernel(_sample_loop, "void(int32[::1], float64[::1], float64[::1], float64[:, ::1], "
                                          "float64[:, ::1], float64[:, ::1], float64[::1])", _sample_numpy)


def _pdf_loop(leaf, wi, density, pdf):
    for i in range(leaf.shape[0]):
        l = leaf[i]
        if l < 0:
            pdf[i] = 0.0
            continue
        pdf[i] = density[l, _cell(wi[i, 0], wi[i, 1], wi[i, 2])] / FOUR_PI


@helper
def _cell(x, y, z):
    """The finest cell of direction (x, y, z) (unit) in the cylindrical map."""
    ix = int(np.floor((z + 1.0) * 0.5 * RES))
    ix = min(max(ix, 0), RES - 1)
    phi = np.arctan2(y, x)
    if phi < 0.0:
        phi += 2.0 * np.pi
    iy = int(np.floor(phi / (2.0 * np.pi) * RES))
    iy = min(max(iy, 0), RES - 1)
    return ix * RES + iy


def cells(wi):
    """The finest cell of each direction (n, 3) (unit): NumPy form of _cell."""
    with np.errstate(invalid="ignore"):
        ix = np.clip(np.floor((wi[:, 2] + 1.0) * 0.5 * RES), 0, RES - 1)
        phi = np.arctan2(wi[:, 1], wi[:, 0])
        phi = np.where(phi < 0.0, phi + 2.0 * np.pi, phi)
        iy = np.clip(np.floor(phi / (2.0 * np.pi) * RES), 0, RES - 1)
    ix = np.where(np.isfinite(ix), ix, 0).astype(np.int64)
    iy = np.where(np.isfinite(iy), iy, 0).astype(np.int64)
    return ix * RES + iy


def _pdf_numpy(leaf, wi, density, pdf):
    ok = leaf >= 0
    pdf[:] = np.where(ok, density[np.where(ok, leaf, 0), cells(wi)] / FOUR_PI, 0.0)


_pdf_kernel = LoopKernel(_pdf_loop, "void(int32[::1], float64[:, ::1], float64[:, ::1], float64[::1])", _pdf_numpy)


@helper
def _record(pg, i, c, lm, out, m):
    """Row m of out gets path i's record of the slot at column c (the
    radiance lm - L then, over the throughput; its moment and cell), if
    that slot holds one; returns the next free row."""
    if pg[i, c] < 0.0:
        return m
    dl = lm - pg[i, c + 1]
    out[m, 0] = pg[i, c]
    out[m, 1] = dl / pg[i, c + 2]
    out[m, 2] = dl * pg[i, c + 3] if pg[i, c + 3] >= 0.0 else -1.0
    out[m, 3] = pg[i, c + 4]
    out[m, 4] = pg[i, c + 5]
    return m + 1


@helper
def _leaf_at(child, x, y, z):
    """The leaf (-1 - child code) holding unit-cube point (x, y, z): the
    tree's walk, halving the cell along x, y, z in turn."""
    node = 0
    depth = 0
    while child[node] >= 0:
        a = depth % 3
        c = x if a == 0 else (y if a == 1 else z)
        c = 2.0 * c
        step = 0
        if c >= 1.0:
            c -= 1.0
            step = 1
        if a == 0:
            x = c
        elif a == 1:
            y = c
        else:
            z = c
        node = child[node] + step
        depth += 1
    return -1 - child[node]


@helper
def _unit(p, lo, inv):
    """unit_cube of one coordinate: NaN and infinities at 0, clamped into [0, 1)."""
    u = (p - lo) * inv
    if not np.isfinite(u):
        u = 0.0
    return min(max(u, 0.0), 1.0 - 1e-12)


def _vertex_loop(kind, lobe_alpha, selection, split, table, p, lo, inv, child, fraction, training,
                 leaf, alpha, rough):
    """Per vertex in one pass: may it be guided (every lobe's table entry
    non-zero, a lobe selected, no second bump normal), its roughness
    (guide_probability's, without ALPHA; -1: not eligible), its leaf (-1:
    the BSDF alone samples) and guide probability fraction[leaf] x roughness."""
    for i in range(kind.shape[0]):
        ok = split[i] == 0
        chosen = False
        r = 0.0
        for j in range(kind.shape[1]):
            t = table[np.int64(kind[i, j]) + 128]
            s = selection[i, j]
            if t == 0:
                ok = False
            if s > 0.0:
                chosen = True
            if t == 1:
                r += s
            else:
                r += s * min(np.sqrt(max(lobe_alpha[i, j], 0.0)), 1.0)
        r = min(max(r, 0.0), 1.0)
        ok = ok and chosen
        rough[i] = r if ok else -1.0
        leaf[i] = -1
        alpha[i] = 0.0
        if not ok or ALPHA * r < MIN_ALPHA:   # a narrow lobe: better sampled by itself
            continue
        lf = _leaf_at(child, _unit(p[i, 0], lo[0], inv[0]), _unit(p[i, 1], lo[1], inv[1]),
                      _unit(p[i, 2], lo[2], inv[2]))
        f = fraction[lf]
        if f < 0.0:
            continue   # the leaf learned no light
        a = f * r
        if training == 0 and a < MIN_ALPHA:
            continue   # after training: a leaf of little guiding is not guided (its CPU)
        leaf[i] = lf
        alpha[i] = a


def _vertex_numpy(kind, lobe_alpha, selection, split, table, p, lo, inv, child, fraction, training,
                  leaf, alpha, rough):
    t = table[kind.astype(np.int64) + 128]
    r = np.where(t == 1, selection, selection * np.minimum(np.sqrt(np.maximum(lobe_alpha, 0.0)), 1.0))
    r = np.clip(r.sum(axis=1), 0.0, 1.0)
    ok = (split == 0) & (t != 0).all(axis=1) & (selection > 0).any(axis=1)
    rough[:] = np.where(ok, r, -1.0)
    lf = np.empty(len(p), np.int32)
    _leaf_numpy(unit_cube(p, lo, inv), child, lf)
    f = fraction[lf]
    a = f * r
    on = ok & (ALPHA * r >= MIN_ALPHA) & (f >= 0.0) & ((training != 0) | (a >= MIN_ALPHA))
    leaf[:] = np.where(on, lf, -1)
    alpha[:] = np.where(on, a, 0.0)


_vertex_kernel = LoopKernel(_vertex_loop, "void(int8[:, ::1], float64[:, ::1], float64[:, ::1], uint8[::1], "
                                          "int8[::1], float64[:, ::1], float64[::1], float64[::1], int32[::1], "
                                          "float64[::1], int64, int32[::1], float64[::1], float64[::1])",
                            _vertex_numpy)



# The mixture at a batch of vertices, in compiled passes that skip the rows
# of no guide leaf (few once leaves learned a fraction of 0).

ONE_MINUS = float(np.nextafter(1.0, 0.0))


def _split_loop(leaf, alpha, u0, chosen, u):
    """Guided rows (leaf >= 0) sample the guide where u0 < alpha; u0 rescaled for the BSDF's lobe choice."""
    for i in range(leaf.shape[0]):
        a = alpha[i] if leaf[i] >= 0 else 0.0
        v = u0[i]
        if leaf[i] >= 0 and v < a:
            chosen[i] = 1
            v = v / a
        else:
            chosen[i] = 0
            if leaf[i] >= 0:
                v = (v - a) / (1.0 - a)
        u[i] = min(v, ONE_MINUS)


def _split_numpy(leaf, alpha, u0, chosen, u):
    on = leaf >= 0
    a = np.where(on, alpha, 0.0)
    c = on & (u0 < a)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(on, np.where(c, u0 / np.where(on, a, 1.0), (u0 - a) / np.where(on, 1.0 - a, 1.0)), u0)
    chosen[:] = c
    u[:] = np.minimum(v, ONE_MINUS)


_split_kernel = LoopKernel(_split_loop, "void(int32[::1], float64[::1], float64[::1], uint8[::1], float64[::1])",
                           _split_numpy)


def _directions_loop(leaf, chosen, u1, u2, tt, bb, ns, cdf, density, wi_l, p_guide):
    """Rows of a guide leaf: chosen ones take the guide's direction (into
    wi_l, in the shading frame tt, bb, ns), every one the guide's pdf of its
    direction; other rows a pdf of 0."""
    for i in range(leaf.shape[0]):
        l = leaf[i]
        if l < 0:
            p_guide[i] = 0.0
            continue
        if chosen[i]:
            x, y, z, p = _sample_one(l, u1[i], u2[i], cdf, density)
            wi_l[i, 0] = x * tt[i, 0] + y * tt[i, 1] + z * tt[i, 2]
            wi_l[i, 1] = x * bb[i, 0] + y * bb[i, 1] + z * bb[i, 2]
            wi_l[i, 2] = x * ns[i, 0] + y * ns[i, 1] + z * ns[i, 2]
            p_guide[i] = p
        else:
            a, b, c = wi_l[i, 0], wi_l[i, 1], wi_l[i, 2]
            x = a * tt[i, 0] + b * bb[i, 0] + c * ns[i, 0]
            y = a * tt[i, 1] + b * bb[i, 1] + c * ns[i, 1]
            z = a * tt[i, 2] + b * bb[i, 2] + c * ns[i, 2]
            p_guide[i] = density[l, _cell(x, y, z)] / FOUR_PI


def _directions_numpy(leaf, chosen, u1, u2, tt, bb, ns, cdf, density, wi_l, p_guide):
    p_guide[:] = 0.0
    on = leaf >= 0
    rows = np.flatnonzero(on & (chosen != 0))
    if len(rows):
        w, p = np.empty((len(rows), 3)), np.empty(len(rows))
        _sample_numpy(leaf[rows], u1[rows], u2[rows], cdf, density, w, p)
        wi_l[rows] = np.stack([(w * f[rows]).sum(axis=1) for f in (tt, bb, ns)], axis=1)
        p_guide[rows] = p
    other = np.flatnonzero(on & (chosen == 0))
    if len(other):
        wl = wi_l[other]
        world = wl[:, 0:1] * tt[other] + wl[:, 1:2] * bb[other] + wl[:, 2:3] * ns[other]
        q = np.empty(len(other))
        _pdf_numpy(leaf[other], world, density, q)
        p_guide[other] = q


_directions_kernel = LoopKernel(_directions_loop, "void(int32[::1], uint8[::1], float64[::1], float64[::1], "
                                                  "float64[:, ::1], float64[:, ::1], float64[:, ::1], "
                                                  "float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1])",
                                _directions_numpy)


def _weights_loop(leaf, chosen, alpha, rough, wo_z, p_guide, bsdf_pdf, f, wi_l, cos_eps, learning, weight, pdf, x):
    """Rows of a guide leaf: p_mix = a p_guide + (1 - a) p_bsdf as pdf,
    f cos / p_mix as weight (chosen rows: from the BSDF's f there; the
    others: their f cos / p_bsdf times p_bsdf / p_mix), and while learning
    x = rough (p_guide - p_bsdf) / p_mix (second_moments)."""
    for i in range(leaf.shape[0]):
        if leaf[i] < 0:
            x[i] = 0.0
            continue
        a = alpha[i]
        pb = bsdf_pdf[i]
        pm = a * p_guide[i] + (1.0 - a) * pb
        s = 1.0 / pm if pm > 0.0 else 0.0
        if chosen[i]:
            k = abs(wi_l[i, 2]) * s if wo_z[i] > cos_eps else 0.0
            for c in range(3):
                weight[i, c] = f[i, c] * k
        else:
            k = pb * s
            for c in range(3):
                weight[i, c] *= k
        pdf[i] = pm
        x[i] = rough[i] * (p_guide[i] - pb) * s if learning else 0.0


def _weights_numpy(leaf, chosen, alpha, rough, wo_z, p_guide, bsdf_pdf, f, wi_l, cos_eps, learning, weight, pdf, x):
    on = leaf >= 0
    c = on & (chosen != 0)
    a = np.where(on, alpha, 0.0)
    pm = a * p_guide + (1.0 - a) * bsdf_pdf
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(pm > 0, 1.0 / np.where(pm > 0, pm, 1.0), 0.0)
    k = np.where(wo_z > cos_eps, np.abs(wi_l[:, 2]) * s, 0.0)
    weight[:] = np.where(c[:, None], f * k[:, None], weight * np.where(on, bsdf_pdf * s, 1.0)[:, None])
    pdf[:] = np.where(on, pm, pdf)
    x[:] = np.where(on & bool(learning), rough * (p_guide - bsdf_pdf) * s, 0.0)


_weights_kernel = LoopKernel(_weights_loop, "void(int32[::1], uint8[::1], float64[::1], float64[::1], float64[::1], "
                                            "float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], float64, "
                                            "int64, float64[:, ::1], float64[::1], float64[::1])", _weights_numpy)


def _nee_loop(leaf, alpha, wi, density, pdf_b, out):
    """The BSDF-side MIS pdf of light samples wi: the mixture at rows of a guide leaf."""
    for i in range(leaf.shape[0]):
        l = leaf[i]
        if l < 0:
            out[i] = pdf_b[i]
        else:
            a = alpha[i]
            out[i] = a * density[l, _cell(wi[i, 0], wi[i, 1], wi[i, 2])] / FOUR_PI + (1.0 - a) * pdf_b[i]


def _nee_numpy(leaf, alpha, wi, density, pdf_b, out):
    p = np.empty(len(leaf))
    _pdf_numpy(leaf, wi, density, p)
    out[:] = np.where(leaf >= 0, alpha * p + (1.0 - alpha) * pdf_b, pdf_b)


_nee_kernel = LoopKernel(_nee_loop, "void(int32[::1], float64[::1], float64[:, ::1], float64[:, ::1], float64[::1], "
                                    "float64[::1])", _nee_numpy)



# ----------------------------------------------------------------------------
# the spatial tree and the directional distributions


class SpatialTree:
    """Binary tree over the unit cube: ``child[node]`` is its first child
    (the second follows it) or -1 - leaf for a leaf; ``depth[node]`` its level."""

    def __init__(self, child, depth):
        self.child = np.ascontiguousarray(child, np.int32)
        self.depth = np.ascontiguousarray(depth, np.int32)
        self.leaves = int((self.child < 0).sum())

    @classmethod
    def root(cls):
        return cls([-1], [0])

    def leaf_of(self, unit):
        out = np.empty(len(unit), np.int32)
        if len(unit):
            _leaf_kernel(np.ascontiguousarray(unit, np.float64), self.child, out)
        return out

    def refine(self, counts, threshold):
        """The tree with each leaf halved (recursively, its records assumed
        to split evenly) while it holds more than ``threshold`` records, to
        MAX_DEPTH levels and MAX_LEAVES leaves; leaves numbered in node order."""
        child, depth = [0], [0]   # the new tree, built breadth-first
        origin = {0: 0}           # new node -> the old node it copies
        records = {}              # new split node -> records expected there
        leaves = 0
        i = 0
        while i < len(child):
            old = origin.get(i)
            if old is not None and self.child[old] >= 0:   # an old inner node: its children follow
                child[i] = len(child)
                for k in range(2):
                    origin[len(child)] = int(self.child[old]) + k
                    child.append(0)
                    depth.append(depth[i] + 1)
                i += 1
                continue
            n = records[i] if old is None else float(counts[-1 - self.child[old]])
            # Each split adds one leaf: the nodes not yet made leaves bound the count.
            if n > threshold and depth[i] < MAX_DEPTH and leaves + (len(child) - i) < MAX_LEAVES:
                child[i] = len(child)
                for _ in range(2):
                    records[len(child)] = n / 2.0
                    child.append(0)
                    depth.append(depth[i] + 1)
            else:
                child[i] = -1 - leaves
                leaves += 1
            i += 1
        return SpatialTree(child, depth)


def densities(energy):
    """(L, BINS) pdf on the unit square of each leaf's quadtree (Mueller's:
    a node split while its energy share exceeds RHO, down to RES x RES),
    from its (L, BINS) cell energies; rows of no energy are 0."""
    n = len(energy)
    e = energy.reshape(n, RES, RES)
    total = e.sum(axis=(1, 2))
    inv = np.where(total > 0, 1.0 / np.where(total > 0, total, 1.0), 0.0)
    pyramid = [e]   # level LEVELS (finest) first
    for _ in range(LEVELS):
        f = pyramid[-1]
        s = f.shape[1] // 2
        pyramid.append(f.reshape(n, s, 2, s, 2).sum(axis=(2, 4)))
    pyramid = pyramid[::-1]   # level 0 (the root) first
    out = np.zeros((n, RES, RES))
    split = np.ones((n, 1, 1), bool)   # the root is always split
    for level in range(1, LEVELS + 1):
        exists = np.repeat(np.repeat(split, 2, axis=1), 2, axis=2)
        share = pyramid[level] * inv[:, None, None]
        split = exists & (share > RHO) if level < LEVELS else np.zeros_like(exists)
        leaf = exists & ~split
        area = 4.0 ** -level
        value = np.where(leaf, share / area, 0.0)
        scale = RES >> level
        out += np.repeat(np.repeat(value, scale, axis=1), scale, axis=2)
    return out.reshape(n, BINS)


class Guide:
    """What a pass samples: the spatial tree, each leaf's density (pdf on
    the unit square per finest cell) and CDF (over cells, in cell order),
    and which leaves guide; positions map to the unit cube by lo, inv_size."""

    def __init__(self, tree, density, guided, lo, inv_size, fraction=None, norm=None):
        self.tree, self.lo, self.inv_size = tree, lo, inv_size
        self.density = np.ascontiguousarray(density)
        cdf = np.cumsum(self.density / BINS, axis=1)
        cdf[:, -1] = np.where(guided, 1.0, cdf[:, -1])
        self.cdf = np.ascontiguousarray(cdf)
        self.guided = guided
        # Each leaf's guide fraction (learned, else ALPHA; -1: not guided)
        # and 1 / its mean record (scales the second moments it learns from).
        f = np.full(len(guided), ALPHA) if fraction is None else np.asarray(fraction, np.float64)
        self.fraction = np.ascontiguousarray(np.where(guided, f, -1.0))
        self.norm = np.ones(len(guided)) if norm is None else np.asarray(norm, np.float64)

    def leaf_of(self, p):
        """Each point's leaf, -1 where its leaf has learned nothing."""
        leaf = self.tree.leaf_of(unit_cube(p, self.lo, self.inv_size))
        return np.where(self.guided[leaf], leaf, -1).astype(np.int32)

    def sample(self, leaf, u1, u2):
        """(directions (n, 3) in world space, their pdf per steradian)."""
        n = len(leaf)
        wi, pdf = np.empty((n, 3)), np.empty(n)
        if n:
            _sample_kernel(np.ascontiguousarray(leaf, np.int32), _c(u1), _c(u2), self.cdf, self.density, wi, pdf)
        return wi, pdf

    def pdf(self, leaf, wi):
        """The guide's pdf per steradian of world directions wi at leaves ``leaf``."""
        out = np.empty(len(leaf))
        if len(leaf):
            _pdf_kernel(np.ascontiguousarray(leaf, np.int32), np.ascontiguousarray(wi, np.float64), self.density, out)
        return out


def _c(a):
    return np.ascontiguousarray(a, np.float64)


def unit_cube(p, lo, inv_size):
    """Points mapped into [0, 1)^3 by the bounds (outside or NaN: clamped)."""
    u = (np.asarray(p, np.float64) - lo) * inv_size
    u = np.where(np.isfinite(u), u, 0.0)
    return np.ascontiguousarray(np.clip(u, 0.0, 1.0 - 1e-12))


def bounds_of(triangles):
    """(lo, 1 / size) of the cube around the triangles (a unit cube when
    there are none; flat or point-like bounds get a size of their own)."""
    bounds = None if triangles is None or not len(getattr(triangles, "p0", ())) else corner_bounds(triangles)
    if bounds is None:
        return np.zeros(3), np.ones(3)
    lo, hi = bounds
    size = float((hi - lo).max())
    size = max(size, 1e-6 * (1.0 + float(np.abs(lo).max())), 1e-12) * (1.0 + 1e-6)
    centre = 0.5 * (lo + hi)
    return centre - 0.5 * size, np.full(3, 1.0 / size)


class PathGuide:
    """The film's guiding state: the spatial tree records go to, their
    fixed-point sums and counts, the Guide passes sample, the schedule."""

    def __init__(self, lo, inv_size, training_samples):
        self.lo, self.inv_size = lo, inv_size
        # Training samples (0: every sample, Cycles' meaning).
        self.training = int(training_samples) if training_samples > 0 else 2 ** 62
        self.tree = SpatialTree.root()
        self._reset()
        self.view = None           # the Guide of the next passes (None: not learned yet)
        self.trained = 0           # samples whose records the guide was built from
        self.stopped = False       # training ended early (STOP_SHARE)

    @property
    def sampled(self):
        """The Guide the next passes sample: none once training stopped
        early (guiding does not pay in this scene: the BSDF alone samples,
        at the unguided cost; ``view`` stays for inspection)."""
        return None if self.stopped else self.view

    def _reset(self):
        self.sums = np.zeros((self.tree.leaves, BINS), np.int64)
        self.counts = np.zeros(self.tree.leaves, np.int64)
        # Per leaf, the estimated second moments of the bounce's estimator
        # with each of FRACTIONS (fixed point) and how many records they hold.
        self.moments = np.zeros((self.tree.leaves, K), np.int64)
        self.moment_counts = np.zeros(self.tree.leaves, np.int64)

    def records_for(self, first_sample):
        """A tile's Records for a pass from sample ``first_sample`` (None once
        training is over: no records)."""
        if first_sample >= self.training:
            return None
        return Records(self.tree, self.lo, self.inv_size)

    def merge(self, records):
        """A tile's summed records (cells, sums, counts): integers, any order."""
        if records is None:
            return
        cells_, sums, counts, *moments = records
        flat = self.sums.reshape(-1)
        flat[cells_] += sums   # cells unique within a tile
        np.add.at(self.counts, cells_ // BINS, counts)
        if moments:   # (unique leaves, (n, K) sums, counts)
            leaves, m, mc = moments
            self.moments[leaves] += m
            self.moment_counts[leaves] += mc

    def update(self, samples):
        """Rebuild the guide from the records since the last rebuild
        (``samples``: samples per pixel they came from) and refine the
        tree the next records go to."""
        if samples <= 0:
            return
        self.trained += samples
        if not self.counts.any():
            return
        energy = self.sums.astype(np.float64) / FIXED
        total = energy.sum(axis=1)
        guided = (self.counts >= MIN_RECORDS) & (total > 0)
        norm = np.where(guided, self.counts / np.where(guided, total, 1.0), 1.0)
        fraction = self.fractions()
        self.view = Guide(self.tree, densities(energy), guided, self.lo, self.inv_size, fraction, norm)
        learnt = self.moment_counts.sum()
        if self.trained >= STOP_AFTER and learnt >= MIN_MOMENTS:
            if self.moment_counts[fraction > 0].sum() < STOP_SHARE * learnt:
                self.training = self.trained   # no more records (records_for) nor rebuilds
                self.stopped = True
        self.tree = self.tree.refine(self.counts, SPLIT_RECORDS * np.sqrt(max(samples, 1)))
        self._reset()


    def fractions(self):
        """Each leaf's guide fraction: the one of FRACTIONS of least second
        moment (a guided one's raised by GUIDE_COST) where the leaf holds
        MIN_MOMENTS guided records, else ALPHA.  From integer sums, so the
        same whatever the batching."""
        out = np.full(self.tree.leaves, ALPHA)
        ok = self.moment_counts >= MIN_MOMENTS
        if ok.any():
            cost = self.moments[ok].astype(np.float64) * np.where(FRACTIONS > 0, 1.0 + GUIDE_COST, 1.0)
            out[ok] = FRACTIONS[np.argmin(cost, axis=1)]   # ties: the smallest fraction
        return out


def second_moments(y, x, old):
    """(n, K) fixed-point estimates of each record's second moment with
    each of FRACTIONS: y = F / q_old (the bounce's contribution, normalized
    by its leaf), x = r (p_guide - p_bsdf) / q_old, old = the fraction that
    sampled it.  E_q_old[y^2 q_old / q_k] = the integral of F^2 / q_k, and
    q_k / q_old = 1 + (a_k - a_old) x."""
    y = np.minimum(y, YMAX)
    ratio = np.maximum(1.0 + (FRACTIONS[None, :] - old[:, None]) * x[:, None], RMIN)
    return np.rint((y * y)[:, None] / ratio * FIXED).astype(np.int64)


class Records:
    """A tile's records before summing: recording cells and values."""

    def __init__(self, tree, lo, inv_size):
        self.tree, self.lo, self.inv_size = tree, lo, inv_size
        self.parts = []
        self.moment_parts = []

    def add(self, cell, value, y=None, x=None, old=None):
        """Records (cell, L cos / p); where y (the radiance the path gathered
        past the vertex, times its leaf's norm; < 0: none) is given, their
        second moments too (second_moments)."""
        # Records of no light count too (the spatial tree splits by how
        # many paths pass, as Mueller's); NaN, inf and negative ones are dropped.
        ok = (cell >= 0) & np.isfinite(value) & (value >= 0)
        if ok.any():
            self.parts.append((cell[ok].astype(np.int64), value[ok]))
        if y is None:
            return
        m = ok & (y >= 0) & np.isfinite(y) & np.isfinite(x) & np.isfinite(old)
        if m.any():
            self.moment_parts.append((cell[m].astype(np.int64) // BINS, second_moments(y[m], x[m], old[m])))

    def summed(self):
        """(unique cells, int64 sums, int64 counts), or None: records
        rounded to fixed point before adding, so any grouping sums alike;
        followed by (unique leaves, (n, K) int64 moment sums, counts) when
        there are second moments."""
        if not self.parts:
            return None
        moments = self._moments()
        cell = np.concatenate([c for c, _ in self.parts])
        q = np.rint(np.minimum(np.concatenate([v for _, v in self.parts]), VMAX) * FIXED).astype(np.int64)
        order = np.argsort(cell, kind="stable")
        cell, q = cell[order], q[order]
        start = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
        counts = np.diff(np.r_[start, len(cell)]).astype(np.int64)
        self.parts = []
        return (cell[start], np.add.reduceat(q, start), counts) + moments

    def _moments(self):
        if not self.moment_parts:
            return ()
        leaf = np.concatenate([l for l, _ in self.moment_parts])
        m = np.concatenate([q for _, q in self.moment_parts])
        self.moment_parts = []
        order = np.argsort(leaf, kind="stable")
        leaf, m = leaf[order], m[order]
        start = np.flatnonzero(np.r_[True, leaf[1:] != leaf[:-1]])
        return leaf[start], np.add.reduceat(m, start, axis=0), np.diff(np.r_[start, len(leaf)]).astype(np.int64)


# ----------------------------------------------------------------------------
# the integrator's side

_ELIGIBLE = {}


def eligible_kinds():
    """Lobe ids a guided vertex may hold: smooth reflection only (memoized per registry size)."""
    key = len(lobe_registry.REGISTRY)
    if key not in _ELIGIBLE:
        _ELIGIBLE[key] = tuple(sorted(d.id for d in lobe_registry.REGISTRY.values()
                                      if d.flags == lobe_registry.REFLECTION and d.eval is not None))
    return _ELIGIBLE[key]


_TABLES = {}


def kind_table(none_kind):
    """int8 table over lobe id + 128 for _vertex_loop: 0 a lobe no guided
    vertex may hold, 1 an eligible diffuse lobe (roughness 1), 2 another
    eligible lobe or none (memoized per registry size)."""
    key = (len(lobe_registry.REGISTRY), none_kind)
    if key not in _TABLES:
        table = np.zeros(256, np.int8)
        diffuse = set(lobe_registry.kinds_of_class("diffuse"))
        for k in eligible_kinds() + (none_kind,):
            table[k + 128] = 1 if k in diffuse else 2
        _TABLES[key] = table
    return _TABLES[key]


class GuideAt:
    """The guide at a batch of vertices: its Guide (None: none yet), each
    vertex's leaf (-1: not guided, the BSDF alone samples there), its guide
    probability and which vertices may be guided (they train the guide);
    ``rough`` their roughness (the guide probability over the leaf's
    fraction) and, once mix ran while learning, ``x`` per row (second_moments')."""

    def __init__(self, view, leaf, alpha, eligible, rough=None, learning=False):
        self.view, self.leaf, self.alpha, self.eligible = view, leaf, alpha, eligible
        self.rough, self.learning = rough, learning
        self.x = None

    def take(self, rows):
        g = GuideAt(self.view, self.leaf[rows], self.alpha[rows], self.eligible[rows],
                    None if self.rough is None else self.rough[rows], self.learning)
        if self.x is not None:
            g.x = self.x[rows]
        return g

    @property
    def rows(self):
        return np.flatnonzero(self.leaf >= 0)


def guide_probability(kind, lobe_alpha, selection, kind_in=np.isin):
    """Each vertex's probability of sampling the guide at a leaf that has
    learned no fraction: ALPHA times the selection-weighted roughness of
    its lobes (diffuse lobes 1, glossy ones their roughness sqrt(alpha)),
    as Cycles' roughness-scaled guiding probability: a narrow lobe is
    better sampled by itself.  (_vertex_loop computes it per vertex.)"""
    diffuse = kind_in(kind, lobe_registry.kinds_of_class("diffuse"))
    rough = np.where(diffuse, 1.0, np.minimum(np.sqrt(np.maximum(lobe_alpha, 0.0)), 1.0))
    return ALPHA * np.clip((selection * rough).sum(axis=1), 0.0, 1.0)


_NO_VIEW = (np.array([-1], np.int32), np.array([-1.0]), np.zeros(3), np.ones(3))


def vertex_guide(view, training, lobes, selection, p, none_kind):
    """(leaf, guide probability, roughness; -1: not eligible) of each
    vertex, by the compiled _vertex_loop (one pass)."""
    n = len(p)
    leaf, alpha, rough = np.empty(n, np.int32), np.empty(n), np.empty(n)
    child, fraction, lo, inv = _NO_VIEW if view is None else (view.tree.child, view.fraction, view.lo,
                                                               view.inv_size)
    split = np.zeros(n, np.uint8) if lobes.diffuse_split is None else lobes.diffuse_split.astype(np.uint8)
    _vertex_kernel(np.ascontiguousarray(lobes.kind, np.int8), _c2(lobes.alpha), _c2(selection), split,
                   kind_table(none_kind), _c2(p), _c(lo), _c(inv), child, fraction, int(bool(training)),
                   leaf, alpha, rough)
    return leaf, alpha, rough


def _c2(a):
    return np.ascontiguousarray(a, np.float64)


def at_vertices(view, recording, v, kind_in, none_kind):
    """The GuideAt of vertices ``v`` (None when nothing is guided or
    recorded there).  While recording, leaves that learned a fraction of 0
    stay guided (with probability 0: their records still learn)."""
    if (view is None and not recording) or len(v) == 0:
        return None
    leaf, alpha, rough = vertex_guide(view, recording, v.lobes, v.selection, v.hit.p, none_kind)
    eligible = rough >= 0.0
    if not eligible.any():
        return None
    if not recording and not (leaf >= 0).any():
        return None
    return GuideAt(view, leaf, alpha, eligible, rough, recording)


def split_choice(guide, u0):
    """(which rows sample the guide, u0 rescaled for the BSDF's lobe choice)."""
    n = len(u0)
    chosen, u = np.empty(n, np.uint8), np.empty(n)
    _split_kernel(np.ascontiguousarray(guide.leaf, np.int32), _c(guide.alpha), _c(u0), chosen, u)
    return chosen.view(bool), u


def nee_pdf(v, wi, pdf_b):
    """The BSDF-side pdf light samples' MIS weighs at vertices ``v``: the
    mixture where guided."""
    g = v.guide
    if g is None or g.view is None:
        return pdf_b
    out = np.empty(len(pdf_b))
    _nee_kernel(np.ascontiguousarray(g.leaf, np.int32), _c(g.alpha), _c2(wi), g.view.density, _c(pdf_b), out)
    return out


def _slots_loop(rows, pg, L, d, ns, beta, prev_pdf, p, child, lo, inv, leaf, x, norm, fraction, out):
    """Guided vertices ``rows`` that go on take the path's next slot of
    ``pg`` (Paths.guide_path): a slot in use first gives its record (cell,
    L cos / p, y, x, old fraction) to ``out``; returns how many it gave."""
    m = 0
    for k in range(rows.shape[0]):
        i = rows[k]
        count = np.int64(pg[i, 0])
        col = 1 + SLOT * (count % SLOTS)
        Lm = (L[i, 0] + L[i, 1] + L[i, 2]) / 3.0
        m = _record(pg, i, col, Lm, out, m)
        lf = _leaf_at(child, _unit(p[i, 0], lo[0], inv[0]), _unit(p[i, 1], lo[1], inv[1]),
                      _unit(p[i, 2], lo[2], inv[2]))
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        cell = _cell(dx, dy, dz) if np.isfinite(dx) and np.isfinite(dy) and np.isfinite(dz) else 0
        pg[i, col] = lf * BINS + cell
        pg[i, col + 1] = Lm
        # Radiance times the cosine at the vertex (the product the BSDF's own
        # sampling leaves out), over the throughput and pdf: Mueller's record.
        c = abs(dx * ns[i, 0] + dy * ns[i, 1] + dz * ns[i, 2])
        pg[i, col + 2] = (beta[i, 0] + beta[i, 1] + beta[i, 2]) / 3.0 * prev_pdf[i] / c
        pg[i, 0] = count + 1
        g = leaf[i]
        pg[i, col + 3] = norm[g] if g >= 0 else -1.0   # no guide here: no second moments
        pg[i, col + 4] = x[i] if g >= 0 else 0.0
        pg[i, col + 5] = fraction[g] if g >= 0 else 0.0
    return m


def _slots_numpy(rows, pg, L, d, ns, beta, prev_pdf, p, child, lo, inv, leaf, x, norm, fraction, out):
    count = pg[rows, 0].astype(np.int64)
    col = 1 + SLOT * (count % SLOTS)
    Lm = L[rows].sum(axis=1) / 3.0
    full = pg[rows, col] >= 0
    r, c = rows[full], col[full]
    m = len(r)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        dl = Lm[full] - pg[r, c + 1]
        out[:m, 0] = pg[r, c]
        out[:m, 1] = dl / pg[r, c + 2]
        out[:m, 2] = np.where(pg[r, c + 3] >= 0, dl * pg[r, c + 3], -1.0)
    out[:m, 3] = pg[r, c + 4]
    out[:m, 4] = pg[r, c + 5]
    lf = np.empty(len(rows), np.int32)
    _leaf_numpy(unit_cube(p[rows], lo, inv), child, lf)
    pg[rows, col] = lf.astype(np.int64) * BINS + cells(d[rows])
    pg[rows, col + 1] = Lm
    cos = np.abs((d[rows] * ns[rows]).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        pg[rows, col + 2] = beta[rows].sum(axis=1) / 3.0 * prev_pdf[rows] / cos
    pg[rows, 0] = count + 1
    g = leaf[rows]
    on = g >= 0
    g = np.where(on, g, 0)
    pg[rows, col + 3] = np.where(on, norm[g], -1.0)
    pg[rows, col + 4] = np.where(on, x[rows], 0.0)
    pg[rows, col + 5] = np.where(on, fraction[g], 0.0)
    return m


_slots_kernel = LoopKernel(_slots_loop, "int64(int64[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], "
                                        "float64[:, ::1], float64[:, ::1], float64[::1], float64[:, ::1], int32[::1], "
                                        "float64[::1], float64[::1], int32[::1], float64[::1], float64[::1], "
                                        "float64[::1], float64[:, ::1])", _slots_numpy)


def _finish_loop(pg, Lm, out):
    """Every slot in use of ending paths' ``pg`` rows: its record (as _slots_loop's) into ``out``."""
    m = 0
    for i in range(pg.shape[0]):
        for s in range(SLOTS):
            m = _record(pg, i, 1 + SLOT * s, Lm[i], out, m)
    return m


def _finish_numpy(pg, Lm, out):
    slots = pg[:, 1:].reshape(len(pg), SLOTS, SLOT)
    i, s = np.nonzero(slots[:, :, 0] >= 0)   # row by row, slot by slot: the loop's order
    q = slots[i, s]
    m = len(i)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        dl = Lm[i] - q[:, 1]
        out[:m, 0] = q[:, 0]
        out[:m, 1] = dl / q[:, 2]
        out[:m, 2] = np.where(q[:, 3] >= 0, dl * q[:, 3], -1.0)
    out[:m, 3] = q[:, 4]
    out[:m, 4] = q[:, 5]
    return m


_finish_kernel = LoopKernel(_finish_loop, "int64(float64[:, ::1], float64[::1], float64[:, ::1])", _finish_numpy)


def _give(rec, out, m):
    if m:
        rec.add(out[:m, 0].astype(np.int64), out[:m, 1], out[:m, 2], out[:m, 3], out[:m, 4])


def record_slots(paths, v, rows, tile):
    """Guided vertices ``rows`` that go on remember a slot (the oldest one
    of the path's given to the tile first): one compiled pass."""
    rec = getattr(tile, "path_records", None)
    pg = paths.guide_path
    if rec is None or not pg.shape[1] or not len(rows):
        return
    g = v.guide
    n = len(pg)
    if g.x is None or g.view is None:   # no guide sampled here: no second moments
        leaf, x, norm, fraction = np.full(n, -1, np.int32), np.zeros(n), np.ones(1), np.zeros(1)
    else:
        leaf, x, norm, fraction = np.ascontiguousarray(g.leaf, np.int32), _c(g.x), g.view.norm, g.view.fraction
    table = np.ascontiguousarray(pg, np.float64)
    out = np.empty((len(rows), 5))
    m = _slots_kernel(np.ascontiguousarray(rows, np.int64), table, _c2(paths.L), _c2(paths.d), _c2(v.hit.ns),
                      _c2(paths.beta), _c(paths.prev_pdf), _c2(v.hit.p), rec.tree.child, _c(rec.lo),
                      _c(rec.inv_size), leaf, x, _c(norm), _c(fraction), out)
    if table is not pg:
        pg[...] = table
    _give(rec, out, m)


def finish_slots(rec, pg, L):
    """Paths ending (their Paths.guide_path rows and radiance): every slot's record."""
    if rec is None or not pg.shape[1] or not len(pg):
        return
    out = np.empty((len(pg) * SLOTS, 5))
    m = _finish_kernel(np.ascontiguousarray(pg, np.float64), _c(L.mean(axis=1)), out)
    _give(rec, out, m)


def start_columns(n, tile):
    """Paths.guide_path for n new paths: COLUMNS per path where the tile
    records, else none."""
    if getattr(tile, "path_records", None) is None:
        return np.zeros((n, 0))
    out = np.full((n, COLUMNS), -1.0)
    out[:, 0] = 0.0
    return out


def mix(v, chosen, u1, u2, wi_l, weight, pdf, delta, eval_pdf):
    """One-sample MIS of the guide and the BSDF at vertices ``v`` (in
    place): rows ``chosen`` take the guide's direction (u1, u2) with the
    BSDF's value there; every guided row's weight and pdf become f cos /
    p_mix and p_mix.  Returns the BSDF's own pdf of each row's direction
    (visibility.ray_kind draws the bounce's kind by it).  While learning,
    sets v.guide.x (second_moments' input).  Two compiled passes around
    the BSDF's evaluation at the chosen rows."""
    from ..microfacet import COS_EPS
    g = v.guide
    n = len(pdf)
    leaf = np.ascontiguousarray(g.leaf, np.int32)
    pick = np.ascontiguousarray(chosen).view(np.uint8)
    tt, bb, ns = _c2(v.tt), _c2(v.bb), _c2(v.hit.ns)
    wl = _c2(wi_l)
    p_guide = np.empty(n)
    _directions_kernel(leaf, pick, _c(u1), _c(u2), tt, bb, ns, g.view.cdf, g.view.density, wl, p_guide)
    rows = np.flatnonzero(chosen)
    bsdf_pdf = np.array(pdf, dtype=np.float64, copy=True)   # pdf itself becomes p_mix below
    f = np.zeros((n, 3))
    if len(rows):
        f[rows], bsdf_pdf[rows] = _eval_rows(v, rows, wl, eval_pdf)
        delta[rows] = False
    learning = g.learning and g.rough is not None
    rough = _c(g.rough) if learning else np.zeros(n)
    w, p = _c2(weight), _c(pdf)
    g.x = np.empty(n)
    _weights_kernel(leaf, pick, _c(g.alpha), rough, _c(v.wo_l[:, 2]), p_guide, bsdf_pdf, f, wl, float(COS_EPS),
                    int(learning), w, p, g.x)
    if not learning:
        g.x = None
    for a, b in ((wi_l, wl), (weight, w), (pdf, p)):
        if a is not b:
            a[...] = b
    return bsdf_pdf


def _eval_rows(v, rows, wi_l, eval_pdf):
    """(f, pdf) of the BSDF at vertices ``rows`` towards wi_l[rows]: over
    those rows' lobes when they are few (a guide fraction learned small),
    else over every row (cheaper than taking most rows' lobes)."""
    n = len(wi_l)
    if 4 * len(rows) < n:
        lobes = take_arrays(v.lobes, rows, n)
        return eval_pdf(lobes, v.wo_l[rows], wi_l[rows], v.selection[rows], v.weights[rows])
    f, pb = eval_pdf(v.lobes, v.wo_l, wi_l, v.selection, v.weights)
    return f[rows], pb[rows]
