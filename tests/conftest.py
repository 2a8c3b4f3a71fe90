import os
import random
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


def pytest_configure(config):
    """The results store's verification sample (tests/simulation/test_store.py) gets a new seed each run, unless
    DPE5G_VERIFY_SEED names one; set here, before xdist starts its workers, so they all share it."""
    if not os.environ.get("DPE5G_VERIFY_SEED"):
        os.environ["DPE5G_VERIFY_SEED"] = str(random.SystemRandom().randrange(2**31))


def pytest_report_header(config):
    seed = os.environ["DPE5G_VERIFY_SEED"]
    return f"results store verification seed: {seed} (DPE5G_VERIFY_SEED={seed} repeats this run's sample)"


def pytest_terminal_summary(terminalreporter):
    """The modules long enough for a reviewer's look (``test_lint.long_modules``), listed after every run."""
    from test_lint import REVIEW_MODULE_LINES, long_modules

    if listed := long_modules():
        terminalreporter.write_line(f"modules over {REVIEW_MODULE_LINES} lines, for review (one concept each?): "
                                    + ", ".join(listed))
