"""``tissuerender`` command line: a thin layer over the Python API.

Exit status: 0 success, 1 a failed check (golden), 2 a user error (bad scene, missing file, bad option;
one line on stderr, never a traceback), 130 interrupted by Ctrl-C (SIGINT), 143 terminated (SIGTERM); after
either, finished frames are kept: rerun with --resume.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading

from sim.errors import MeshError
from tissuerender import golden, load_scene, lookdev, make_plan, render
from tissuerender import show as show_command
from tissuerender.checks import check_scene
from tissuerender.distributed import add_dask_options
from tissuerender.errors import UserError
from tissuerender.files import OutputError
from tissuerender.report import accuracy as report_accuracy


def _cmd_render(args) -> int:
    scene = load_scene(args.scene)
    if args.workers is not None or args.scheduler is not None:
        from tissuerender.distributed import render_distributed

        result = render_distributed(scene, args.out, resume=args.resume, progress=not args.quiet, frames=args.frames,
                                    workers=args.workers, scheduler=args.scheduler,
                                    announce=(lambda line: None) if args.quiet else print)
    else:
        result = render(scene, args.out, resume=args.resume, progress=not args.quiet, frames=args.frames)
    if not args.quiet:
        print(f"wrote {len(result.written)} file(s) to {result.out_dir}"
              + (f", kept {len(result.skipped)} finished frame(s)" if result.skipped else "")
              + f"; manifest: {result.out_dir / 'manifest.json'}")
    if result.stale:
        print(f"note: {result.out_dir} also holds {len(result.stale)} frame file(s) this render did not write "
              f"({result.stale[0].name}, …), left from an earlier render; manifest.json lists this render's frames",
              file=sys.stderr)
    return 0


def _cmd_batch(args) -> int:
    from tissuerender.batch import load_spec, run_batch  # imports dask only when asked for

    spec = load_spec(args.spec)
    data = run_batch(spec, args.out, resume=args.resume, progress=not args.quiet, workers=args.workers,
                     scheduler=args.scheduler, announce=(lambda line: None) if args.quiet else print)
    if not args.quiet:
        print(f"{data['sequences_complete']} of {data['sequences_total']} sequence(s) complete in {args.out}; "
              f"batch manifest: {args.out}/batch.json")
    return 0


def _cmd_plan(args) -> int:
    scene = load_scene(args.scene)
    print(f"scene {scene.name!r} ({scene.path})")
    print(make_plan(scene).describe())
    return 0


def _cmd_validate(args) -> int:
    for path in args.scenes:
        scene = load_scene(path)
        checked = check_scene(scene)  # builds what render builds before its first frame: "ok" means it renders
        print(f"{path}: ok ({scene.name!r}, {len(scene.objects)} object(s), {scene.output.frames} frame(s), "
              f"{len(checked.plan.stages)} stage(s) planned)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tissuerender", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("render", help="render a scene's image sequence")
    p.add_argument("scene")
    p.add_argument("-o", "--out", default="out", help="output folder (default: out)")
    p.add_argument("--resume", action="store_true", help="keep finished frames and render only the missing ones")
    p.add_argument("--frames", type=int, default=None, help="render only the first N frames")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_dask_options(p, "frames")
    p.set_defaults(func=_cmd_render)
    p = sub.add_parser("batch", help="render many sequences from a base scene plus randomisation "
                                     "(docs/batch-format.md)")
    p.add_argument("spec", help="the batch spec file (TOML)")
    p.add_argument("-o", "--out", required=True, help="the batch folder: one folder per sequence and batch.json")
    p.add_argument("--resume", action="store_true", help="keep finished sequences and frames; render the rest")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_dask_options(p, "sequences")
    p.set_defaults(func=_cmd_batch)
    p = sub.add_parser("plan", help="print the stages a scene will run, and why")
    p.add_argument("scene")
    p.set_defaults(func=_cmd_plan)
    p = sub.add_parser("validate", help="check scene files without rendering")
    p.add_argument("scenes", nargs="+")
    p.set_defaults(func=_cmd_validate)
    golden.add_cli(sub)
    lookdev.add_cli(sub)
    report_accuracy.add_cli(sub)
    show_command.add_cli(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a job scheduler's time limit): stops a command exactly as Ctrl-C does, so the
    atomic writers remove their temporaries and the finished frames stay."""


def _terminate(signum, frame):
    raise Terminated


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "frames", None) is not None and args.frames < 1:
        parser.error(f"--frames: expected a positive number, found {args.frames}")
    if getattr(args, "workers", None) is not None and args.workers < 1:
        parser.error(f"--workers: expected a positive number, found {args.workers}")
    in_main_thread = threading.current_thread() is threading.main_thread()  # signal.signal works only there
    previous = signal.signal(signal.SIGTERM, _terminate) if in_main_thread else None
    try:
        return int(args.func(args) or 0)
    except (UserError, MeshError) as e:
        hint = ""
        if isinstance(e, OutputError) and args.command in ("render", "batch"):
            hint = "; the finished frames are kept: make room (or fix the folder) and rerun with --resume"
        print(f"error: {e}{hint}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        how = "terminated" if isinstance(e, Terminated) else "interrupted"
        if args.command in ("render", "batch"):
            print(f"{how}: finished frames are kept; rerun with --resume to continue", file=sys.stderr)
        elif args.command == "report":
            print(f"{how}: finished cases are kept in {args.out}/cases; rerun the same command to continue",
                  file=sys.stderr)
        else:
            print(f"{how}: {args.command} wrote nothing further", file=sys.stderr)
        return 143 if isinstance(e, Terminated) else 130
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


if __name__ == "__main__":
    sys.exit(main())
