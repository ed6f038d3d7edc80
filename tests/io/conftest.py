from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="session")
def aris_sample() -> Path:
    return DATA / "aris" / "sample.aris"


@pytest.fixture(scope="session")
def oculus_sample() -> Path:
    return DATA / "oculus" / "one_ping_8bit.raw"
