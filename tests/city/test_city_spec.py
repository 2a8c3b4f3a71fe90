"""A city's settings (``trace.CitySpec``) refused when built, each naming its field; a clearance no point of the region
meets refused by the placement instead of drawing forever; the tracing code's digest blind to those refusals only."""

import math

import numpy as np
import pytest

from dpe5g.city import trace

BAD = {
    "scene": ("paris", "scene must be one of"),
    "side_m": (math.nan, "side_m"),
    "n_bs": (2, "n_bs"),
    "n_ue": (0, "n_ue"),
    "samples_per_src": (0, "samples_per_src"),
    "power_dbm": (math.nan, "power_dbm"),
    "fc_hz": (math.inf, "fc_hz"),
    "bandwidth_hz": (-1.0, "bandwidth_hz"),
    "clearance_m": (50.0, "clearance_m"),
    "seed": (-1, "seed"),
    "diffraction": ("False", "diffraction must be True or False"),
    "refraction": (1, "refraction must be True or False"),
    "max_depth": (2.5, "max_depth"),
}


@pytest.mark.parametrize("field", BAD)
def test_a_bad_setting_is_refused_naming_its_field(field):
    value, needle = BAD[field]
    with pytest.raises(ValueError, match=needle):
        trace.CitySpec(**{field: value})


def test_equal_settings_are_one_spec():
    a = trace.CitySpec(n_bs=26.0, power_dbm=24, seed=np.int64(20261205), diffraction=np.bool_(True))
    assert a == trace.CitySpec() and a.to_dict() == trace.CitySpec().to_dict()
    assert type(a.n_bs) is int and type(a.power_dbm) is float and a.diffraction is True


def test_a_clearance_no_point_meets_is_refused_not_drawn_forever(monkeypatch):
    """Every draw indoors (a stand-in for the scene): ``outdoor_points`` stops after ``MAX_DRAW_ROUNDS`` rounds with a
    ValueError naming clearance_m; one outdoor point in eight is found at once."""
    monkeypatch.setattr(trace, "outdoors", lambda scene, p, clearance_m: np.zeros(len(p), bool))
    with pytest.raises(ValueError, match=r"clearance_m 3.0 m: 0 of 2000 points drawn .* fewer than the 10 wanted"):
        trace.outdoor_points(None, (0.0, 0.0, 100.0, 100.0), 10, 3.0, np.random.default_rng(0))
    monkeypatch.setattr(trace, "outdoors", lambda scene, p, clearance_m: np.arange(len(p)) % 8 == 0)
    assert trace.outdoor_points(None, (0.0, 0.0, 100.0, 100.0), 10, 3.0, np.random.default_rng(0)).shape == (10, 2)


def test_the_digest_reads_the_code_that_traces_not_its_refusals():
    base = "def f(x):\n    '''doc'''\n    from .a import b\n    y = b(x)\n    return y\n"
    same = ("def f(x):\n    from ..c.a import b\n    if x < 0:\n        raise ValueError('x')\n    y = b(x)\n"
            "    return y\n")
    assert trace.tracing_code(base) == trace.tracing_code(same)
    assert trace.tracing_code(base) != trace.tracing_code(base.replace("b(x)", "b(x + 1)"))
    assert trace.tracing_code(base) != trace.tracing_code(base.replace("    y = b(x)\n", "    if x < 0:\n        x = 0\n    y = b(x)\n"))
    cls = "class S:\n    a: int = 1\n\n    def __post_init__(self):\n        check(self.a)\n"
    assert trace.tracing_code(cls) == trace.tracing_code(cls.replace("check(self.a)", "check(self.a, 2)"))
    assert trace.tracing_code(cls) != trace.tracing_code(cls.replace("a: int = 1", "a: int = 2"))
