import pytest

from datapipe.draws import seeds


def test_plan_sums_and_respects_bounds():
    for base in range(20):
        plan = seeds.plan_scenes(17, 2, 5, base)
        assert sum(plan) == 17
        assert all(2 <= n <= 5 for n in plan[:-1]) and 1 <= plan[-1] <= 5
    assert seeds.plan_scenes(17, 2, 5, 3) == seeds.plan_scenes(17, 2, 5, 3)
    assert seeds.plan_scenes(50, 1, 5, 1) != seeds.plan_scenes(50, 1, 5, 2)


def test_seeds_depend_only_on_base_and_index():
    assert seeds.scene_seed(7, 3) == seeds.scene_seed(7, 3)
    assert len({seeds.scene_seed(7, i) for i in range(1000)}) == 1000
    assert seeds.scene_seed(7, 3) != seeds.scene_seed(8, 3)
    assert all(0 <= seeds.render_seed(1, i, r) < 2**31 for i in range(20) for r in range(5))


@pytest.mark.parametrize("n_scenes,n", [(1, 1), (4, 2), (7, 3), (2, 5)])
def test_shards_partition_scenes(n_scenes, n):
    got = [i for k in range(n) for i in seeds.shard_scenes(n_scenes, (k, n))]
    assert got == list(range(n_scenes))


@pytest.mark.parametrize("bad", ["1", "2/2", "-1/3", "a/b", "0/0"])
def test_bad_shard_text(bad):
    with pytest.raises(ValueError, match="shard"):
        seeds.parse_shard(bad)


def _plan_one_draw_per_scene(num_renders, lo, hi, base):
    """The original loop (one rng draw per scene): the vectorised plan must keep its numbers."""
    import numpy as np
    rng = np.random.default_rng(seeds._derive(seeds._PLAN, base))
    plan, left = [], num_renders
    while left > 0:
        n = min(int(rng.integers(lo, hi + 1)), left)
        plan.append(n)
        left -= n
    return plan


@pytest.mark.parametrize("num", [0, 1, 2, 5, 17, 333])
@pytest.mark.parametrize("lo,hi", [(1, 1), (1, 3), (2, 5), (3, 3), (4, 20)])
def test_vectorised_plan_equals_one_draw_per_scene(num, lo, hi):
    for base in (0, 1, 99):
        assert seeds.plan_scenes(num, lo, hi, base) == _plan_one_draw_per_scene(num, lo, hi, base)


def test_plan_of_the_largest_run_is_cheap_and_bad_bounds_raise():
    """Defect #3: min/max 0/0 looped forever, min > max was a NumPy traceback, 10^9 planned for minutes."""
    plan = seeds.plan_scenes(seeds.MAX_PLAN_RENDERS, 1, 3, 5)     # well under a second (not asserted)
    assert sum(plan) == seeds.MAX_PLAN_RENDERS and all(1 <= n <= 3 for n in plan)
    for lo, hi in [(0, 0), (3, 2), (-1, 2)]:
        with pytest.raises(ValueError, match="renders per scene"):
            seeds.plan_scenes(10, lo, hi, 0)
    with pytest.raises(ValueError, match="num_renders"):
        seeds.plan_scenes(10**9, 1, 2, 0)
