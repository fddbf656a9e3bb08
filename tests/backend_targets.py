"""What the hybrid-model test files share: both backends as a parameter (C skipped where no
compiler works) and a private compile cache per test (their runs must not replay each other's
records; each starts with the C runtime's objects built, conftest's seed_c_runtime)."""
from __future__ import annotations

import pytest
from conftest import seed_c_runtime

from bgc.backends.c import build as cbuild


def has_cc() -> bool:
    return cbuild.available()


TARGETS = ["numpy", pytest.param("c", marks=pytest.mark.skipif(not has_cc(),
                                                                reason="no C compiler"))]


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BGC_CACHE_DIR", str(seed_c_runtime(tmp_path / "cache")))
