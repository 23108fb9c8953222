"""The worker warm-up of a batch (:func:`scenesim.batch.tasks.warm_worker`)."""

import sys

import pytest

from noise.errors import ParameterTypeError
from scenesim.batch.tasks import warm_worker


def test_warm_worker_imports_what_a_task_imports_lazily():
    took = warm_worker(("gls", "stcal-ols_c"))
    assert isinstance(took, float) and took >= 0.0
    for name in ("photutils.aperture", "scenesim.pipelines.instrument",
                 "scenesim.pipelines.zeroframe", "stcal.ramp_fitting.ramp_fit"):
        assert name in sys.modules, name


@pytest.mark.parametrize("bad", [5, "gls", [1], None, ("gls", 2)])
def test_warm_worker_refuses_what_is_not_a_list_of_names(bad):
    with pytest.raises(ParameterTypeError, match="'fitters' must be a list of fitter "
                                                 "names"):
        warm_worker(bad)
