import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

ROOT = Path(__file__).resolve().parents[1]

# JAX compiles on first use; hypothesis' default deadline would flag that as flaky.
settings.register_profile("dpe5g", deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=25)
settings.load_profile("dpe5g")


@pytest.fixture
def root() -> Path:
    return ROOT
