"""Mend the ROS 2 Jazzy PyPI wheels' known defect so that colcon can build rosidl packages.

The wheels' exported CMake targets (share/*/cmake/export_*__rosidl_generator_pyExport.cmake)
name the wheel builder's paths /opt/python/cp311-cp311/include/python3.11 and
/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include; CMake's generate step
fails on non-existent include paths. This rewrites those two paths, inside the venv only, to
this interpreter's include directory and the venv's numpy include directory. Idempotent.
"""
import sys
import sysconfig
from pathlib import Path

BUILDER = "/opt/python/cp311-cp311"
BAD_PY_INCLUDE = BUILDER + "/include/python3.11"
BAD_NUMPY_INCLUDE = BUILDER + "/lib/python3.11/site-packages/numpy/_core/include"


def main() -> int:
    import numpy

    prefix = Path(sys.prefix)
    py_include = sysconfig.get_paths()["include"]
    if not Path(py_include, "Python.h").is_file():
        print(f"fix_ros_wheels: no Python.h in {py_include}; install the Python headers", file=sys.stderr)
        return 1
    np_include = numpy.get_include()
    changed = 0
    for path in sorted(prefix.glob("share/*/cmake/*.cmake")):
        text = path.read_text()
        if BUILDER not in text:
            continue
        new = text.replace(BAD_NUMPY_INCLUDE, np_include).replace(BAD_PY_INCLUDE, py_include)
        if new != text:
            path.write_text(new)
            changed += 1
    print(f"fix_ros_wheels: {changed} CMake export file(s) rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main())
