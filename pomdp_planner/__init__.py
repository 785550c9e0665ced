"""pomdp_planner: online sensor management with myopic policy bounds (Lauri et al.).

``pomdp_planner.core`` is the pure numerical core (numpy, scipy, clarabel; never rclpy).
``pomdp_planner.nodes`` holds the thin ROS 2 nodes built on top of it.

Ctrl-C while one of the package's executables starts: importing a node (rclpy, numpy, scipy)
takes most of a second, and a ``KeyboardInterrupt`` there would print a traceback from inside an
import. So when this process *is* one of the package's executables (a console script of
:data:`EXECUTABLES`, ``python -m pomdp_planner`` or ``python -m pomdp_planner.nodes.<name>``),
this first import of the package installs a SIGINT handler that ends the process at once with
exit code 130 and one line; the executable puts its own in place once it has started (a node's
``runtime.run_nodes``, the command line's ``pomdp_planner.__main__``). Imported by any other
program, the package touches no signal.
"""

import os as _os
import signal as _signal
import sys as _sys
import threading as _threading

__version__ = "0.1.0"

#: The package's executables (setup.py's console scripts; a test checks that they agree).
EXECUTABLES = ("pomdp-planner", "target_simulator", "belief_filter", "planner", "closed_loop", "measurement_adapter",
               "sensor_manager", "run_recorder", "belief_visualizer")
#: Exit code of an interrupted start (128 + SIGINT, the shell's convention).
EXIT_INTERRUPTED = 130


def _started_as_executable(argv: list) -> str:
    """The name of the package's executable this process runs (``argv``: the interpreter's command
    line, ``sys.orig_argv``), or ``""``."""
    if "-m" in argv:
        i = argv.index("-m")
        module = argv[i + 1] if i + 1 < len(argv) else ""
        ours = module == "pomdp_planner" or (module.startswith("pomdp_planner.nodes.")
                                           and module.rsplit(".", 1)[-1] in EXECUTABLES)
        return module if ours else ""
    script = next((a for a in argv[1:] if not a.startswith("-")), "")
    name = _os.path.basename(script)
    return name if name in EXECUTABLES else ""


def _interrupted_while_starting(signum, frame) -> None:
    _os.write(2, f"{_STARTING}: interrupted while starting\n".encode())
    _os._exit(EXIT_INTERRUPTED)


_STARTING = _started_as_executable(list(getattr(_sys, "orig_argv", _sys.argv)))
if (_STARTING and _threading.current_thread() is _threading.main_thread()
        and _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler):
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
