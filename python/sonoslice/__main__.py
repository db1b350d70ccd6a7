"""``python -m sonoslice dataset SPEC --out DIR``: the command line of :mod:`sonoslice.datasets.writer`
(``sonoslice dataset ...`` runs this with the same arguments). It parses arguments and formats
results; the work is the library's.

Exit status as for every sonoslice command: 0 done; 1 bad input or a failure (one line
``sonoslice: error: ...`` naming the input); 2 a usage error; 130/143 interrupted (temporaries
removed; run the same command again to resume).
"""
import argparse
import os
import signal
import sys
import time


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line ending with the --help to read, exit status 2 (the C++ CLI's rule)."""

    def error(self, message):
        self.exit(2, f"sonoslice: error: {message}; see '{self.prog} --help'\n")


def _parser():
    """The top-level parser and the dataset command's."""
    parser = _Parser(prog="sonoslice", description="sonoslice commands written in Python")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    d = commands.add_parser(
        "dataset", prog="sonoslice dataset", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Write a dataset of images from a SPEC (YAML or JSON) as WebDataset shards plus a "
                    "manifest (docs/datasets.md). Complete shards in DIR are kept: rerun an interrupted "
                    "run to finish it.",
        epilog="Exit status: 0 done, 1 bad input or a failure (one line naming the input), 2 a usage error.")
    d.add_argument("spec", metavar="SPEC", help="the dataset's SPEC (docs/dataset_example.yaml)")
    d.add_argument("--out", metavar="DIR", help="output folder (shared by all workers with --scheduler)")
    d.add_argument("--scheduler", metavar="S",
                   help="local:N (a Dask LocalCluster of N worker processes) or a Dask scheduler address "
                        "tcp://HOST:8786; default: this process")
    d.add_argument("--threads", type=int, metavar="N",
                   help="CPU threads per process, at least 1 (default: all cores; local:N divides them)")
    d.add_argument("--dry-run", action="store_true",
                   help="print the plan (shards, samples, images, estimated size and time) and write nothing")
    d.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    return parser, d


def _size(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1000


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _print_plan(p, out_dir) -> None:
    spec = p.spec
    print(f"SPEC {spec.name}: {p.samples} samples in {p.shards} shard{'s' * (p.shards != 1)} of up to "
          f"{spec.shard_samples}" + (f", to {out_dir}" if out_dir else ""))
    for s in spec.samplers:
        print(f"  samplers[{s.index}] {s.type}: {s.count} samples (global {s.first}..{s.first + s.count - 1}) "
              f"of volume {s.volume} with probe {s.probe}: {', '.join(k.kind for k in s.images)}")
    print(f"images: {p.images} ({spec.image_format})")
    print(f"estimated size: {_size(p.estimated_bytes)}")
    timed = ", ".join(f"{n}" for n in p.batch.values())
    print(f"estimated time: {_duration(p.estimated_seconds)} in one process on this machine (setup "
          f"{_duration(p.setup_seconds)}, then samples timed in batches of {timed} per sampler)")
    print("nothing written (--dry-run)")


def _summary(manifest, out_dir: str, seconds: float) -> str:
    size = sum(s["bytes"] for s in manifest["shards"])
    return (f"sonoslice: {manifest['samples']} samples ({manifest['images']} images) in "
            f"{len(manifest['shards'])} shards, {_size(size)}, in {out_dir} (manifest.json); "
            f"{_duration(seconds)}, {manifest['samples'] / max(seconds, 1e-9):.0f} samples/s")


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__


def _die_by(signum: int) -> None:
    """Ends the process by ``signum`` (status 128 + signum), as sonoslice's other commands do."""
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


class _Terminated(BaseException):
    """SIGTERM, raised where the program is, so that temporaries are removed on the way out."""


def _on_sigterm(signum, frame):
    raise _Terminated()


def _dataset_command(args) -> int:
    from .datasets import writer as ds
    if args.threads is not None and args.threads < 1:
        print(f"sonoslice: error: --threads {args.threads}: must be at least 1", file=sys.stderr)
        return 1
    start = time.perf_counter()
    result = ds.write_dataset(args.spec, args.out, scheduler=args.scheduler, dry_run=args.dry_run,
                              progress=not args.quiet, threads=args.threads)
    if args.dry_run:
        _print_plan(result, args.out)
    elif not args.quiet:
        print(_summary(result, args.out, time.perf_counter() - start), file=sys.stderr)
    return 0


def main(argv=None) -> int:
    parser, dataset_parser = _parser()
    args = parser.parse_args(argv)
    if args.out is None and not args.dry_run:
        dataset_parser.error("the following arguments are required: --out")
    signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _dataset_command(args)
    except KeyboardInterrupt:
        print("sonoslice: interrupted; run the same command again to resume", file=sys.stderr)
        _die_by(signal.SIGINT)
    except _Terminated:
        print("sonoslice: terminated; run the same command again to resume", file=sys.stderr)
        _die_by(signal.SIGTERM)
    except (ValueError, OSError, RuntimeError) as e:
        print(f"sonoslice: error: {_one_line(e)}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
