"""common.limits.check_params: the sets a parameter choice asks of each worker, against the budget."""
from __future__ import annotations

import pytest

from igi.common import limits
from igi.common.params import make_params


@pytest.fixture
def budget_1m():
    limits.set_memory_budget("1M")
    yield
    limits.set_memory_budget(None)


def test_the_still_cameras_vpl_count_sizes_the_sets_the_moving_one_only_caps_it(budget_1m):
    # 25 sets of 2 + 4·L VPLs × 96 B with no photons: well inside a quarter of 1 MiB
    small = dict(interleave=5, photons=0, direct_vpls=2, indirect_vpls=4, light_path_length=4)
    limits.check_params(make_params(**small))
    limits.check_params(make_params(**small, moving_indirect_vpls=1024))  # a cap: never more VPLs
    with pytest.raises(limits.LimitError, match="VPLs"):
        limits.check_params(make_params(**dict(small, indirect_vpls=1024)))
