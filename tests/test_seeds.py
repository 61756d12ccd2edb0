import pytest

from datapipe import seeds


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
