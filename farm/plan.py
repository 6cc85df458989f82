"""What a farm job renders: frames, chunks, sample ranges, output names,
and what is left to do when a job is resumed."""
import os
import re
from dataclasses import dataclass, field

STATE_DIR = '.farm'


def parse_frames(text):
    """'1-250', '7', '1-10,20,30-32' -> sorted list of distinct frames."""
    frames = set()
    for part in str(text).replace(' ', '').split(','):
        match = re.fullmatch(r'(-?\d+)(?:(?:-|\.\.)(-?\d+))?', part)
        if not match:
            raise ValueError(f"bad frame range {part!r} in {text!r}: use e.g. 1-250 or 1,5,10-12")
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) is not None else first
        if last < first:
            raise ValueError(f"frame range {part!r} ends before it starts")
        frames.update(range(first, last + 1))
    if not frames:
        raise ValueError("no frames to render")
    return sorted(frames)


def format_frames(frames):
    """[1, 2, 3, 7] -> '1-3,7' (the inverse of parse_frames)."""
    return ",".join(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]) for run in chunks(frames, len(frames)))


def chunks(frames, size):
    """Runs of consecutive frames, at most ``size`` long (one Blender start each)."""
    if size < 1:
        raise ValueError("--chunk must be at least 1")
    out, run = [], []
    for frame in frames:
        if run and (frame != run[-1] + 1 or len(run) == size):
            out.append(run)
            run = []
        run.append(frame)
    return out + [run]


def sample_ranges(samples, parts):
    """[0, samples) cut into ``parts`` disjoint ranges as even as possible."""
    if parts < 1 or samples < parts:
        raise ValueError(f"cannot split {samples} samples into {parts} shards")
    edges = [samples * i // parts for i in range(parts + 1)]
    return list(zip(edges[:-1], edges[1:]))


def frame_path(out_dir, frame, layer=None):
    suffix = f".{layer}" if layer else ""
    return os.path.join(out_dir, f"frame_{frame:04d}{suffix}.exr")


def shard_dir(out_dir):
    return os.path.join(out_dir, 'shards')


@dataclass
class Job:
    """Everything a worker needs to run a task of this job (picklable)."""
    blend: str
    out_dir: str
    frames: list
    samples: int = 0                 # 0: the scene's own setting
    split: int = 1                   # shards per frame
    chunk: int = 1
    blender: str = ''                # '' = the bpy module in a subprocess
    python: str = ''                 # interpreter with bpy (bpy-module mode)
    threads: int = 0                 # render threads per task (0 = all cores)
    blend_sha256: str = ''
    ember_version: str = ''          # what the client has (farm/versions.py);
    blender_version: str = ''        # '' skips that check on the workers
    extra_env: dict = field(default_factory=dict)

    def fingerprint(self):
        """What must not change between a job and its --resume."""
        return {'blend_sha256': self.blend_sha256, 'samples': self.samples, 'split': self.split,
                'ember_version': self.ember_version, 'blender_version': self.blender_version}


@dataclass(frozen=True)
class Task:
    kind: str                        # 'chunk', 'shard' or 'merge'
    frames: tuple
    start: int = 0
    end: int = 0

    @property
    def key(self):
        if self.kind == 'chunk':
            return f"ember-chunk-{self.frames[0]}-{self.frames[-1]}"
        if self.kind == 'shard':
            return f"ember-shard-{self.frames[0]}-s{self.start}-{self.end}"
        return f"ember-merge-{self.frames[0]}"


def tasks(job):
    """Every task of the job, merges after the shards they need."""
    if job.split <= 1:
        return [Task('chunk', tuple(run)) for run in chunks(job.frames, job.chunk)]
    out = []
    for frame in job.frames:
        out += [Task('shard', (frame,), a, b) for a, b in sample_ranges(job.samples, job.split)]
        out.append(Task('merge', (frame,)))
    return out
