"""The line every benchmark prints first: the machine, the versions, the date and the BLAS threads."""

from __future__ import annotations

import os
import platform
import time

import numpy as np


def machine_line(*details: str) -> str:
    """``# node machine, cores, python, numpy, date, OMP_NUM_THREADS`` then ``details``, comma-separated."""
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    parts = [
        f"# {platform.node() or 'machine'} {platform.machine()}",
        f"{os.cpu_count()} cores",
        f"python {platform.python_version()}",
        f"numpy {np.__version__}",
        time.strftime("%Y-%m-%d"),
        f"OMP_NUM_THREADS={threads}",
    ]
    return ", ".join(parts + [d for d in details if d])
