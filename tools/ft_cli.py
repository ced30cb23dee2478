"""Subcommands of ./ft (run inside the workspace environment that ./ft sets up)."""
from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
INSTALL = ROOT / "install"

ENV_VARS = (
    "VIRTUAL_ENV", "PATH", "LD_LIBRARY_PATH", "PYTHONPATH", "AMENT_PREFIX_PATH",
    "CMAKE_PREFIX_PATH", "COLCON_PREFIX_PATH", "RMW_IMPLEMENTATION", "_ROS_WHEELS_BOOTSTRAP_COMPLETE",
)


def executable(package: str, name: str) -> Path:
    """Where `ros2 run PACKAGE NAME` finds a node: install/<pkg>/lib/<pkg>/<name>."""
    path = INSTALL / package / "lib" / package / name
    if not path.is_file():
        lib = INSTALL / package / "lib" / package
        have = sorted(p.name for p in lib.iterdir()) if lib.is_dir() else []
        raise SystemExit(f"ft: error: no executable {name!r} in package {package!r}; "
                         f"expected one of {', '.join(have) or '(package not built)'}")
    return path


def cmd_run(args: argparse.Namespace) -> int:
    exe = executable(args.package, args.executable)
    os.execv(str(exe), [str(exe), *args.args])
    return 0  # not reached


def cmd_test(args: argparse.Namespace) -> int:
    chosen = any(Path(a.split("::")[0]).exists() for a in args.pytest_args if not a.startswith("-"))
    cmd = [sys.executable, "-m", "pytest", *([] if chosen else [str(ROOT / "tests")]), *args.pytest_args]
    rc = subprocess.call(cmd, cwd=ROOT)
    if rc == 5:
        print("ft: error: pytest collected no tests", file=sys.stderr)
        return 1
    return rc


def cmd_env(args: argparse.Namespace) -> int:
    for name in ENV_VARS:
        if name in os.environ:
            print(f"export {name}={shlex.quote(os.environ[name])}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    import demo
    return demo.main(args)


def cmd_thesis(args: argparse.Namespace) -> int:
    import thesis_cmd
    return thesis_cmd.main(args)


def cmd_discover(args: argparse.Namespace) -> int:
    import discover_cmd
    return discover_cmd.main(args)


def cmd_bag(args: argparse.Namespace) -> int:
    from bag_tools.cli import main as bag_main
    return bag_main(args.bag_args)


def cmd_bench(args: argparse.Namespace) -> int:
    script = ROOT / "benchmarks" / f"bench_{args.name}.py"
    if not script.is_file():
        have = sorted(p.stem.removeprefix("bench_") for p in (ROOT / "benchmarks").glob("bench_*.py"))
        raise SystemExit(f"ft: error: no benchmark {args.name!r}; expected one of {', '.join(have)}")
    return subprocess.call([sys.executable, str(script), *args.bench_args], cwd=ROOT)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="./ft", description="The force tester workspace: live ROS 2 correction graph, bags, tests.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    d = sub.add_parser("demo", help="run sim + correction + validator over DDS on the test sets, "
                                    "record a bag, print per-set scores")
    import demo
    demo.add_arguments(d)
    d.set_defaults(func=cmd_demo)

    th = sub.add_parser("thesis", help="the thesis's top-speed predictions and Tables 7-9 beside ours "
                                       "(--json FILE for the figures)")
    import thesis_cmd
    thesis_cmd.add_arguments(th)
    th.set_defaults(func=cmd_thesis)

    di = sub.add_parser("discover", help="find what the simulation gets wrong in measured data: name the "
                                         "cause, extend the model, measure the gain")
    import discover_cmd
    discover_cmd.add_arguments(di)
    di.set_defaults(func=cmd_discover)

    t = sub.add_parser("test", help="run the test suite (pytest); extra arguments go to pytest")
    t.add_argument("pytest_args", nargs=argparse.REMAINDER)
    t.set_defaults(func=cmd_test)

    r = sub.add_parser("run", help="run a node like `ros2 run PACKAGE EXECUTABLE [--ros-args ...]`")
    r.add_argument("package")
    r.add_argument("executable")
    r.add_argument("args", nargs=argparse.REMAINDER)
    r.set_defaults(func=cmd_run)

    b = sub.add_parser("bag", help="record, play and inspect rosbag2 MCAP bags (./ft bag --help)",
                       add_help=False)
    b.add_argument("bag_args", nargs=argparse.REMAINDER)
    b.set_defaults(func=cmd_bag)

    e = sub.add_parser("env", help="print the environment as shell exports: eval \"$(./ft env)\"")
    e.set_defaults(func=cmd_env)

    be = sub.add_parser("bench", help="run a benchmark script from benchmarks/ (e.g. ./ft bench correction)")
    be.add_argument("name")
    be.add_argument("bench_args", nargs=argparse.REMAINDER)
    be.set_defaults(func=cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    passthrough = {'test': 'pytest_args', 'run': 'args', 'bag': 'bag_args', 'bench': 'bench_args'}
    if extra and args.command not in passthrough:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:  # options meant for pytest, the node or the bag tool
        setattr(args, passthrough[args.command], extra + getattr(args, passthrough[args.command]))
    try:
        return args.func(args)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
