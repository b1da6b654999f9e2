from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "volumes"


def pytest_report_header(config):
    return f"shared data: {SHARED} ({'present' if SHARED.is_dir() else 'absent: data tests skip'})"


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def shared_file(rel: str) -> Path:
    p = SHARED / rel
    if not p.exists():
        pytest.skip(f"{p} not found: the shared volume data is not beside this checkout")
    return p
