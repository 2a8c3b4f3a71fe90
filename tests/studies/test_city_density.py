"""The density sweep (``city_density``): the stored networks are current and checksummed, each the book's square with
``factor`` times its BSs (the first the city's own) and the same UEs; their experiments run on the UEs that hear
four BSs; bad factors are refused."""

import numpy as np
import pytest

from dpe5g.city import dataset as city_paths
from dpe5g.studies import city as city_study, city_density


@pytest.fixture(scope="module")
def city():
    return city_paths.load_city(city_study.CITY)


@pytest.fixture(scope="module")
def networks():
    return {f: city_paths.load_city(city_density.density_name(city_study.CITY, f)) for f in city_density.FACTORS}


def test_every_network_is_stored_and_current(city, networks):
    """``make reproduce`` would trace none of them again; the factor-1 network has the city's BSs, every network the
    city's square and the same UEs, and factor times the BSs."""
    ue = networks[1].ue_xyz
    for f, net in networks.items():
        assert city_density.is_current(city, f), f
        assert net.n_bs == f * city.n_bs and net.n_ue == city_density.DENSITY_UES
        assert np.array_equal(net.region, city.region) and np.array_equal(net.ue_xyz, ue)
        assert city_paths.read_record(net.name)["factor"] == f
    assert np.array_equal(networks[1].bs_xyz, city.bs_xyz)


def test_each_networks_trials_are_its_ues_that_hear_four_bss(networks):
    """The experiments' trials (``traced_draw``'s population) are the UEs ``city_study.heard_per_ue`` counts as
    hearing four BSs, the same trials for both clock priors."""
    for f, net in networks.items():
        exps = city_density.experiments(f)
        configs = [e.to_dict() for e in exps.values()]  # the same trials: only the DPE's clock window differs
        assert {k for k in configs[0] if configs[0][k] != configs[1][k]} == {"name", "clock_window"}, f
        n = {e.run.n_trials for e in exps.values()}
        assert n == {int(np.sum(city_study.heard_per_ue(net) >= city_study.CITY_M[0]))}, (f, n)
        assert len({e.run.name for e in exps.values()}) == len(exps)


@pytest.mark.parametrize("factor", [0, 3, 2.0, "2", None, True])
def test_a_factor_not_swept_is_refused(city, factor):
    with pytest.raises(ValueError, match=r"factor must be one of 1, 2, 4, got"):
        city_density.density_spec(city, factor)
