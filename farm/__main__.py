"""Command line of the Ember render farm (see farm/__init__.py and README)."""
import argparse
import glob
import os
import sys

from . import plan


def parse(argv):
    parser = argparse.ArgumentParser(prog='python -m farm', description="Ember render farm on Dask")
    sub = parser.add_subparsers(dest='command', required=True)

    render = sub.add_parser('render', help="render frames of a .blend on a Dask cluster")
    render.add_argument('blend')
    render.add_argument('--frames', required=True, help="e.g. 1-250 or 1,5,10-12")
    render.add_argument('--chunk', type=int, default=1, help="frames per task (default 1)")
    render.add_argument('--samples', type=int, default=0, help="samples per pixel (default: the scene's)")
    render.add_argument('--split-samples', type=int, default=1, metavar='K',
                        help="render each frame as K shards of disjoint sample ranges, then merge")
    where = render.add_mutually_exclusive_group(required=True)
    where.add_argument('--scheduler', help="address of a running scheduler, tcp://HOST:8786")
    where.add_argument('--local', type=int, metavar='N', help="start a local cluster of N workers")
    render.add_argument('-o', '--output', required=True, help="output folder (shared by all machines)")
    render.add_argument('--blender', default='', help="Blender binary with Ember installed "
                        "(default: the bpy module of this Python)")
    render.add_argument('--threads', type=int, default=0, help="render threads per task (default: every core, "
                        "shared out among --local workers)")
    render.add_argument('--resume', action='store_true', help="skip frames and shards already on disk")
    render.add_argument('--retries', type=int, default=2, help="reruns of a failing task (default 2)")

    worker = sub.add_parser('worker', help="run a Dask worker with one render slot")
    worker.add_argument('scheduler', help="tcp://HOST:8786")
    worker.add_argument('--name')
    worker.add_argument('--render-threads', type=int, default=0, help="threads per render (0 = all cores)")
    worker.add_argument('--local-directory')

    state = sub.add_parser('status', help="workers, jobs, tasks and ETA of a running farm")
    state.add_argument('--scheduler', required=True, help="tcp://HOST:8786")
    state.add_argument('--json', action='store_true', help="print the same as JSON")

    merge = sub.add_parser('merge', help="merge shard files of one frame into an image")
    merge.add_argument('shards', nargs='+', help="shard files (patterns with * are expanded)")
    merge.add_argument('--plan', help="the planned sample ranges, e.g. 0-32,32-64: exactly these are "
                       "merged, each once (default: the given shards must tile [0, N))")
    merge.add_argument('-o', '--output', required=True, help="output .exr")
    return parser.parse_args(argv)


def make_job(args):
    from .client import blend_hash
    from .versions import WorkerMismatch, blender_version, ember_version
    blend = os.path.abspath(args.blend)
    if not os.path.isfile(blend):
        raise SystemExit(f"no such .blend file: {blend}")
    if args.split_samples > 1 and not args.samples:
        raise SystemExit("--split-samples needs --samples (the total to split)")
    if args.split_samples > 1 and args.samples < args.split_samples:
        raise SystemExit(f"cannot split {args.samples} samples into {args.split_samples} shards")
    if args.blender and not os.access(args.blender, os.X_OK):
        raise SystemExit(f"--blender {args.blender} is not an executable")
    try:
        frames = plan.parse_frames(args.frames)
    except ValueError as err:
        raise SystemExit(str(err)) from None
    try:
        versions = {'ember_version': ember_version(), 'blender_version': blender_version(args.blender, sys.executable)}
    except WorkerMismatch as err:
        raise SystemExit(f"this machine cannot plan the job: {err}") from None
    threads = args.threads or (max(1, (os.cpu_count() or 1) // args.local) if args.local else 0)
    return plan.Job(blend=blend, out_dir=os.path.abspath(args.output), frames=frames, samples=args.samples,
                    split=max(1, args.split_samples), chunk=args.chunk, blender=args.blender,
                    python=sys.executable, threads=threads, blend_sha256=blend_hash(blend), **versions)


def cmd_render(args):
    from distributed import Client, LocalCluster
    from . import client as farm_client
    job = make_job(args)
    if args.local:
        cluster = LocalCluster(n_workers=args.local, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        dask_client = Client(cluster)
    else:
        cluster, dask_client = None, Client(args.scheduler)
    try:
        written, failures = farm_client.run(dask_client, job, args.resume, retries=args.retries)
    finally:
        dask_client.close()
        if cluster is not None:
            cluster.close()
    for path in written:
        print("wrote", path)
    for failure in failures:
        print("FAILED", failure, file=sys.stderr)
    return 1 if failures else 0


def cmd_merge(args):
    from .merge import merge_to_image
    from .shardfile import ShardError
    paths = []
    for arg in args.shards:
        paths += sorted(glob.glob(arg)) if any(c in arg for c in '*?[') else [arg]
    try:
        ranges = [tuple(int(x) for x in r.split('-')) for r in args.plan.split(',')] if args.plan else None
    except ValueError:
        print(f"bad --plan {args.plan!r}: use e.g. 0-32,32-64", file=sys.stderr)
        return 2
    try:
        meta = merge_to_image(paths, args.output, plan=ranges)
    except ShardError as err:
        print(f"merge refused: {err}", file=sys.stderr)
        return 1
    print(f"merged {len(meta['shards'])} shards, samples [{meta['sample_start']}, {meta['sample_end']}) "
          f"of frame {meta['frame']} -> {args.output}")
    return 0


def main(argv=None):
    args = parse(sys.argv[1:] if argv is None else argv)
    if args.command == 'render':
        return cmd_render(args)
    if args.command == 'merge':
        return cmd_merge(args)
    if args.command == 'status':
        from .status import main as status_main
        return status_main(args.scheduler, args.json)
    from .worker import main as worker_main
    worker_main(args.scheduler, args.name, args.render_threads, args.local_directory)
    return 0


if __name__ == '__main__':
    sys.exit(main())
