import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run (CI fails or passes the same way twice);
# VDP_HYPOTHESIS=explore draws new ones, to look for cases the fixed set misses.
settings.register_profile("fixed", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("VDP_HYPOTHESIS", "fixed"))

ROOT = Path(__file__).resolve().parents[1]
# the team's shared folder sits beside the checkout (as in CI); /work/shared on a dev box
SHARED = next((p for p in (ROOT.parent / "shared", Path("/work/shared")) if p.is_dir()), ROOT.parent / "shared")
REAL = SHARED / "data" / "real"

# DBCs derived from opendbc go to a per-run cache, not the user's ~/.cache
os.environ.setdefault("VDP_CACHE_DIR", tempfile.mkdtemp(prefix="vdp-test-cache-"))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


def pytest_collection_modifyitems(config, items):
    """The files with the most slow tests first, each file's tests kept together and in order:
    under ``--dist loadfile`` a worker takes whole files in this order, so a long file started
    last would run alone at the end while the other worker idles."""
    order: dict = {}
    for k, item in enumerate(items):
        n, first = order.get(item.path, (0, k))
        order[item.path] = (n + (item.get_closest_marker("slow") is not None), first)
    items.sort(key=lambda item: (-order[item.path][0], order[item.path][1]))
