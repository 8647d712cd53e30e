import os
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# DBCs derived from opendbc go to a per-run cache, not the user's ~/.cache
os.environ.setdefault("VDP_CACHE_DIR", tempfile.mkdtemp(prefix="vdp-test-cache-"))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT
