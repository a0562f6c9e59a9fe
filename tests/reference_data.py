"""Published reference data sets used as test oracles."""

import numpy as np


def nbs14_1000() -> np.ndarray:
    """NIST SP 1065 Table 31 1000-point data set (docs/reference/noise-formulas.md §1.1)."""
    n = np.empty(1000, dtype=np.int64)
    n[0] = 1234567890
    for i in range(999):
        n[i + 1] = (16807 * n[i]) % 2147483647
    return n / 2147483647.0


#: NBS14 10-point frequency data (Riley test suite Table I; docs/reference/noise-formulas.md §1.2)
NBS14_10_FREQ = np.array([892, 809, 823, 798, 671, 644, 883, 903, 677], dtype=float)
