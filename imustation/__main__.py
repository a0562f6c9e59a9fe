"""``python -m imustation`` is the same as the ``imustation`` console script."""

from imustation.cli import main

main()
