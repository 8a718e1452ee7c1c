"""Stand-ins for the graph's nodes in tests/rrg_bringup/test_launch_escalation.py: child
processes whose way of ending is known, without ROS.

    python tests/launch_children.py sleep [--ignore INT,TERM] [ARG ...]   # until a signal ends it
    python tests/launch_children.py die SECONDS STATUS [ARG ...]          # exits on its own

Each prints ``ready`` and its arguments once its signal handlers are in place, and a line for
every signal it ignores.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time


def report(signum: int, _frame) -> None:
    print(f"ignored {signal.Signals(signum).name}")


def main() -> int:
    p = argparse.ArgumentParser()
    modes = p.add_subparsers(dest="mode", required=True)
    sleep = modes.add_parser("sleep")
    sleep.add_argument("--ignore", default="", help="signals to ignore, e.g. INT,TERM")
    die = modes.add_parser("die")
    die.add_argument("seconds", type=float)
    die.add_argument("status", type=int)
    args, extra = p.parse_known_args()
    ignored = [s for s in getattr(args, "ignore", "").split(",") if s]
    for name in ("INT", "TERM"):
        sig = getattr(signal, f"SIG{name}")
        if name in ignored:
            signal.signal(sig, report)
        else:
            signal.signal(sig, signal.SIG_DFL)  # ends the process, as an unhandled signal does
    print(f"ready {extra}", flush=True)
    if args.mode == "die":
        time.sleep(args.seconds)
        return args.status
    while True:
        time.sleep(0.05)
        sys.stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
