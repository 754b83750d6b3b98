import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def find_data_dir() -> Path | None:
    """The third-party data: $TACTILE6D_DATA, else ../shared/data beside the repository."""
    env = os.environ.get("TACTILE6D_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(REPO.parent / "shared" / "data")
    return next((p for p in candidates if (p / "ycb").is_dir()), None)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    found = find_data_dir()
    if found is None:
        pytest.skip("no data directory (set TACTILE6D_DATA or put the data at ../shared/data)")
    return found
