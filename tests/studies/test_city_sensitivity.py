"""The tracer's settings tested (``city_sensitivity``): the stored subsets are current and checksummed, the subset
traced with the city's settings is the stored city's, and settings that cannot mean anything are refused."""

import numpy as np
import pytest

from dpe5g.city import dataset as city_paths, trace as city_trace
from dpe5g.studies import city as city_study, city_sensitivity


@pytest.fixture(scope="module")
def city():
    return city_paths.load_city(city_study.CITY)


def test_every_variant_is_stored_and_current(city):
    """``make reproduce`` would trace none of them again; each loads with its checksum and records its settings."""
    for key, (label, settings) in city_sensitivity.VARIANTS.items():
        assert city_sensitivity.is_current(city, key), key
        sub, meta = city_sensitivity.load_variant(city.name, key)
        assert meta["label"] == label and {k: meta["spec"][k] for k in settings} == settings
        assert sub.n_ue == city_sensitivity.SUBSET_UES and np.array_equal(sub.bs_xyz, city.bs_xyz)
        assert np.array_equal(sub.ue_xyz, city.ue_xyz[:city_sensitivity.SUBSET_UES])
    assert set(city_sensitivity.load_materials(city.name))  # the scene's materials, recorded


def city_key(city):
    """The variant whose settings are the stored city's."""
    keys = [k for k in city_sensitivity.VARIANTS if city_sensitivity.variant_spec(city, k).to_dict() == city.spec]
    assert len(keys) == 1, keys
    return keys[0]


def test_the_subset_traced_with_the_citys_settings_is_the_stored_citys(city):
    """The same links (UE, BS) as the stored city's first UEs, their power within ``city_paths.VERIFY_POWER_DB`` and
    their first path at the same delay: the subset's other rows differ from the city by their settings alone."""
    sub, _ = city_sensitivity.load_variant(city.name, city_key(city))
    n = city_sensitivity.SUBSET_UES
    mine = {(u, b): i for i, (u, b) in enumerate(zip(sub.link_ue, sub.link_bs))}
    rows = np.nonzero(city.link_ue < n)[0]
    theirs = {(u, b): i for i, (u, b) in zip(rows, zip(city.link_ue[rows], city.link_bs[rows]))}
    assert set(mine) == set(theirs)
    i, j = np.array([mine[k] for k in theirs]), np.array(list(theirs.values()))
    assert np.max(np.abs(sub.power_db[i] - city.power_db[j])) <= city_paths.VERIFY_POWER_DB
    assert np.max(np.abs(sub.first_excess_s()[i] - city.first_excess_s()[j])) <= city_paths.VERIFY_EXCESS_S


def test_settings_that_mean_nothing_are_refused():
    with pytest.raises(ValueError, match="scattering_coefficient must be > 0 exactly when diffuse_reflection"):
        city_trace.CitySpec(diffuse_reflection=False)
    with pytest.raises(ValueError, match="scattering_coefficient must be > 0 exactly when diffuse_reflection"):
        city_trace.CitySpec(scattering_coefficient=0.0)
    with pytest.raises(ValueError, match="scattering_coefficient"):
        city_trace.CitySpec(scattering_coefficient=1.5)
    with pytest.raises(ValueError, match="max_depth"):
        city_trace.CitySpec(max_depth=-1)
    with pytest.raises(ValueError, match="variant must be one of"):
        city_sensitivity.variant_name("munich", "diffuse09")


def test_each_subset_runs_as_a_deployment_of_its_own(city):
    """Its deployment is the city's BSs, found by name in the store (``deployment.builtin``); its experiment runs
    every UE of the subset that hears M BSs, and no more (``city_draw.population`` refuses one trial more)."""
    from dpe5g.phy import deployment
    from dpe5g.simulation import traced_draw

    assert deployment.builtin("munich-settings-nothing") is None and deployment.builtin("../munich") is None
    for key in city_sensitivity.VARIANTS:
        e = city_sensitivity.settings_experiment(key)
        assert deployment.builtin(e.scenario.deployment) is not None
        np.testing.assert_allclose(e.load_deployment().bs_xyz, city.bs_xyz)
        sub, links = traced_draw.population(e)
        assert sub.name == city_sensitivity.variant_name(city.name, key) and len(links.ue_index) == e.run.n_trials
        with pytest.raises(ValueError, match="n_trials must be at most"):
            traced_draw.population(e.replace(n_trials=e.run.n_trials + 1))
