"""The second city (``city_second``): stored and current, the book's settings in another scene; its experiments are the
city chapter's, each on its own trials (the first UEs that hear M BSs, all of them where fewer than ``CITY_TRIALS``)."""

import numpy as np
import pytest

from dpe5g.city import dataset as city_paths, trace as city_trace
from dpe5g.studies import catalog, city as city_study, city_second


@pytest.fixture(scope="module")
def second():
    return city_paths.load_city(city_second.SECOND_CITY)


def test_the_second_city_is_stored_current_and_the_books_settings_elsewhere(second):
    """``make reproduce`` would not trace it again; only the scene and the number of UEs differ from the book's city."""
    assert city_second.is_current()
    book = city_trace.CitySpec().to_dict()
    assert {k for k, v in second.spec.items() if book[k] != v} == {"scene", "n_ue"}
    assert second.n_ue == city_second.SECOND_UES and second.n_bs == book["n_bs"]
    assert not np.array_equal(second.region, city_paths.load_city(city_study.CITY).region)
    city_paths.load_view(second.name)  # its 3-D view (the map's buildings), checksummed


def test_its_experiments_are_the_city_chapters_on_its_own_trials(second):
    """The same experiments as the book's city but for the deployment and the trials, which are the first UEs that
    hear M BSs, at most ``CITY_TRIALS[M]``; all are in the results store's catalogue."""
    mine, book = city_second.all_experiments(), city_study.all_experiments()
    assert len(mine) == len(book)
    for a, b in zip(mine, book):
        da, db = a.to_dict(), b.to_dict()
        assert {k for k in da if da[k] != db[k]} <= {"name", "deployment", "n_trials"}, a.run.name
        assert a.run.name == b.run.name.replace(city_study.CITY, city_second.SECOND_CITY, 1)
        m = a.receiver.m_values[0]
        heard = int(np.sum(city_study.heard_per_ue(second, m) >= m))
        assert a.run.n_trials == min(city_study.CITY_TRIALS[m], heard), (a.run.name, heard)
    stored = {(e.run.name, e.run.n_trials) for e in catalog.store_experiments()}
    assert {(e.run.name, e.run.n_trials) for e in mine} <= stored
