"""The ``imustation`` command (console script and ``python -m imustation``).

A capture's stop signals are recorded before the command line's modules load
(:mod:`imustation.stopsignals`): a SIGINT or SIGTERM in the first moments then
finishes the run file like one during the recording.
"""

from __future__ import annotations

import sys

from imustation import stopsignals


def main() -> None:
    if stopsignals.is_capture(sys.argv[1:]):
        stopsignals.record()
    from imustation.cli import main as cli_main

    cli_main()


if __name__ == "__main__":
    main()
