"""Mend the ROS 2 Jazzy PyPI wheels' known defect so that colcon can build rosidl packages.

The wheels' exported CMake targets (share/*/cmake/export_*__rosidl_generator_pyExport.cmake)
name the wheel builder's paths /opt/python/cp311-cp311/include/python3.11 and
/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include; CMake's generate step
fails on non-existent include paths. This rewrites those two paths, inside the venv only, to
this interpreter's include directory and the venv's numpy include directory. Idempotent.

A file is rewritten as a new file renamed over the old one, never edited in place: uv installs a wheel's files as
hard links to its cache, and an edit in place would change the cache's copy, so that every later venv would get
this venv's paths. A path that another venv wrote there (a cache mended in place before this rule) is rewritten
too: any Python or numpy include directory that is not this venv's.
"""
import os
import re
import sys
import sysconfig
from pathlib import Path

BUILDER = "/opt/python/cp311-cp311"
# an include directory of some interpreter or some venv's numpy, in a CMake list or string
PY_INCLUDE = re.compile(r'[^;"\s]*/include/python3\.11(?=[;"])')
NUMPY_INCLUDE = re.compile(r'[^;"\s]*/site-packages/numpy/_core/include(?=[;"])')


def mend(prefix: Path, py_include: str, np_include: str) -> int:
    """Rewrite the include directories of PREFIX's CMake export files; the number of files rewritten."""
    changed = 0
    for path in sorted(prefix.glob("share/*/cmake/*.cmake")):
        text = path.read_text()
        if "numpy/_core/include" not in text and BUILDER not in text:
            continue
        new = NUMPY_INCLUDE.sub(lambda m: np_include, text)
        new = PY_INCLUDE.sub(lambda m: py_include, new)
        if new != text:
            tmp = path.with_name(path.name + ".mending")
            tmp.write_text(new)
            os.replace(tmp, path)     # a new file: the hard-linked original (uv's cache) is left as it was
            changed += 1
    return changed


def main() -> int:
    import numpy

    py_include = sysconfig.get_paths()["include"]
    if not Path(py_include, "Python.h").is_file():
        print(f"fix_ros_wheels: no Python.h in {py_include}; install the Python headers", file=sys.stderr)
        return 1
    changed = mend(Path(sys.prefix), py_include, numpy.get_include())
    print(f"fix_ros_wheels: {changed} CMake export file(s) rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main())
