import os
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# the team's shared folder sits beside the checkout (as in CI); /work/shared on a dev box
SHARED = next((p for p in (ROOT.parent / "shared", Path("/work/shared")) if p.is_dir()), ROOT.parent / "shared")
REAL = SHARED / "data" / "real"

# DBCs derived from opendbc go to a per-run cache, not the user's ~/.cache
os.environ.setdefault("VDP_CACHE_DIR", tempfile.mkdtemp(prefix="vdp-test-cache-"))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT
