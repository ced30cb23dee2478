import gc
import sys

from .main import main

code = main()
# What is left is freed by the process's exit: freezing it spares the interpreter's collections at shutdown, which
# would walk every object (40-70 ms for `./ft bag correct`, docs/speed-setup.md).
gc.freeze()
sys.exit(code)
