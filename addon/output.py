"""Engine images -> Blender's render result, plus progress reporting.

The engine hands over float32 RGBA with row 0 at the top; Blender's result
rows start at the bottom.  ``foreach_set`` with a contiguous float32 buffer
writes a 1920x1080 frame in milliseconds (assigning ``rect`` takes seconds).
"""
import sys
import time

import numpy as np

# Callables (samples_done, samples_total, stats) told about every pass; the
# command-line renderer adds a progress bar here.
progress_listeners = []


def to_blender_pixels(image):
    """(H, W, 4) top-row-first -> flat bottom-row-first float32 RGBA.

    Returns (pixels, bad) where bad counts non-finite values replaced by 0: a
    NaN must never reach the user's image.
    """
    flipped = np.ascontiguousarray(image[::-1], dtype=np.float32)
    finite = np.isfinite(flipped)
    bad = int(flipped.size - np.count_nonzero(finite))
    if bad:
        flipped = np.where(finite, flipped, np.float32(0.0))
    return flipped.reshape(-1), bad


BAND = 256  # rows checked for NaN at a time: no full-frame mask


def _zero_nonfinite_in_place(image):
    """Replace NaN and Inf by 0, a band of rows at a time; returns how many."""
    bad = 0
    for lo in range(0, len(image), BAND):
        band = image[lo:lo + BAND]
        finite = np.isfinite(band)
        count = band.size - int(np.count_nonzero(finite))
        if count:
            band[~finite] = 0.0
            bad += count
    return bad


def _flip_rows_in_place(image):
    """Reverse the row order with one row of scratch (top-first <->
    Blender's bottom-first): a flipped copy would cost a full frame,
    530 MB at 8K."""
    height = len(image)
    scratch = np.empty_like(image[0])
    for top in range(height // 2):
        bottom = height - 1 - top
        scratch[...] = image[top]
        image[top] = image[bottom]
        image[bottom] = scratch


def write_rgba_in_place(render_pass, image):
    """Write a contiguous float32 (H, W, 4) top-first image into a pass
    without copying it: flip it in place, write, flip it back.  NaN/Inf
    become 0 (in the image too); returns how many there were."""
    bad = _zero_nonfinite_in_place(image)
    _flip_rows_in_place(image)
    try:
        set_pass(render_pass, image.reshape(-1))
    finally:
        _flip_rows_in_place(image)
    return bad


def set_pass(render_pass, flat):
    """foreach_set that accepts 5.0's flat and 3.4's (pixels, channels) layouts."""
    try:
        render_pass.rect.foreach_set(flat)
    except TypeError:
        render_pass.rect.foreach_set(flat.reshape(-1, render_pass.channels))


def result_views(engine, width, height, layer_name):
    """The names of the render result's views: [''] without multiview,
    ['left', 'right'] in stereo, the enabled views' names otherwise (read
    from a 1x1 result discarded after, as Cycles' BlenderSession::render)."""
    result = engine.begin_result(0, 0, 1, 1, layer=layer_name)
    try:
        names = [view.name for view in result.views]
    finally:
        engine.end_result(result, cancel=True, do_merge_results=False)
    return names if any(names) else ['']


class ResultWriter:
    """Owns one render result (one view layer, the border window, one view
    or the only one) while rendering."""

    def __init__(self, engine, width, height, layer_name, view=''):
        self.engine = engine
        self.width = width
        self.height = height
        self.result = engine.begin_result(0, 0, width, height, layer=layer_name, view=view)
        self.layer = self.result.layers[0]
        self.nonfinite = 0

    def write(self, image, extra=None):
        """Copy an RGBA image (and optional named passes) into the result."""
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"the renderer returned a {image.shape[1]}x{image.shape[0]} image "
                             f"for a {self.width}x{self.height} window")
        combined = self.layer.passes["Combined"]
        if image.shape[2] == 4 and image.dtype == np.float32 and image.flags.c_contiguous:
            bad = write_rgba_in_place(combined, image)
        else:
            pixels, bad = to_blender_pixels(image[..., :4])
            set_pass(combined, pixels)
        self.nonfinite = max(self.nonfinite, bad)
        for name, data in (extra or {}).items():
            render_pass = self.layer.passes.get(name)
            if render_pass is not None and data is not None:
                values = data.reshape(self.height, self.width, -1)[..., :render_pass.channels]
                set_pass(render_pass, to_blender_pixels(values)[0])
        self.engine.update_result(self.result)

    def add_metadata(self, fields):
        """Render-result metadata (Cryptomatte manifests), written into the
        engine's whole result as Cycles does (get_result): the result of
        begin_result does not carry metadata over."""
        if not fields:
            return
        get_result = getattr(self.engine, 'get_result', None)
        target = get_result() if get_result is not None else self.result
        add = getattr(target, 'stamp_data_add_field', None)
        if add is None:
            return
        for key, value in fields.items():
            add(key, value)

    def finish(self):
        # cancel=False keeps what was written: an interrupted render shows its
        # partial image instead of black.
        self.engine.end_result(self.result, cancel=False)


def format_stats(samples_done, samples_total, stats):
    parts = [f"Sample {samples_done}/{samples_total}"]
    rays = stats.get('rays_per_second')
    if rays:
        parts.append(f"{rays / 1e6:.2f} Mrays/s")
    left = stats.get('seconds_left')
    if left is not None and samples_done < samples_total:
        parts.append(f"{_clock(left)} left")
    return " | ".join(parts)


def _clock(seconds):
    seconds = max(int(round(seconds)), 0)
    return f"{seconds // 60:02d}:{seconds % 60:02d}"


def break_requested(engine):
    """Blender's cancel flag (Esc in the UI).  A function of its own so that
    tests can stand in for a user pressing Esc, which background mode lacks."""
    return engine.test_break()


class Progress:
    """The engine's progress callback, bound to a Blender RenderEngine.

    ``info`` is the render's log entry: it receives the time from the start of
    render() to the first displayed pass, and the pass count.
    """

    def __init__(self, engine, writer, samples_total, info):
        self.engine = engine
        self.writer = writer
        self.samples_total = samples_total
        self.info = info
        self.samples_done = 0
        self.cancelled = False
        self.shown_progress = 0.0
        self.shown_seconds_left = None

    def on_pass(self, image, samples_done, stats):
        self.writer.write(image)
        self.info['passes'] += 1
        if self.info['passes'] == 1:
            self.info['first_pass_seconds'] = time.perf_counter() - self.info['started']
        self.samples_done = samples_done
        total = stats.get('samples_total') or self.samples_total
        stats = self._monotone(stats)
        self.engine.update_stats("", format_stats(samples_done, total, stats))
        self.shown_progress = max(self.shown_progress, min(samples_done / max(total, 1), 1.0))
        self.engine.update_progress(self.shown_progress)
        for listener in progress_listeners:
            listener(samples_done, total, stats)

    def on_status(self, text, fraction):
        """Work before the first pass (the kernel compile) in the status bar."""
        self.engine.update_stats("", "Ember: " + text)
        self.engine.update_progress(min(max(fraction, 0.0), 1.0))

    def _monotone(self, stats):
        """The status bar's time left never goes up (a slower pass would
        otherwise raise the estimate): show the smallest estimate so far."""
        left = stats.get('seconds_left')
        if left is None:
            return stats
        if self.shown_seconds_left is not None:
            left = min(left, self.shown_seconds_left)
        self.shown_seconds_left = left
        return dict(stats, seconds_left=left)

    def should_stop(self):
        if not self.cancelled and break_requested(self.engine):
            self.cancelled = True
        return self.cancelled


def text_progress_bar(stream=sys.stderr, width=30):
    """A listener drawing a one-line progress bar (for the command line)."""
    def draw(samples_done, samples_total, stats):
        filled = int(width * samples_done / max(samples_total, 1))
        bar = "#" * filled + "-" * (width - filled)
        end = "\n" if samples_done >= samples_total else ""
        stream.write(f"\r[{bar}] {format_stats(samples_done, samples_total, stats)}   {end}")
        stream.flush()
    return draw
