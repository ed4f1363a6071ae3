"""The scene seed ranges of python/cnfmp/seeds.json keep the relations the benchmark relies on,
so an edit of the file that would let training, validation and evaluation share scenes fails
here."""

from cnfmp.seeds import HELDOUT_SEEDS, NFMP_GRID_SEEDS, TRAIN_SEEDS, VALIDATION_SEEDS


def within(inner: range, outer: range) -> bool:
    return outer.start <= inner.start and inner.stop <= outer.stop


def test_every_range_is_a_nonempty_run_of_whole_seeds():
    for seeds in (TRAIN_SEEDS, VALIDATION_SEEDS, HELDOUT_SEEDS, NFMP_GRID_SEEDS):
        assert seeds.start >= 0 and len(seeds) > 0 and seeds.step == 1


def test_validation_and_grid_scenes_are_training_scenes_and_held_out_ones_are_not():
    assert within(VALIDATION_SEEDS, TRAIN_SEEDS)
    assert within(NFMP_GRID_SEEDS, TRAIN_SEEDS)
    assert HELDOUT_SEEDS.start >= TRAIN_SEEDS.stop or HELDOUT_SEEDS.stop <= TRAIN_SEEDS.start
    # Datasets number their demonstrations from the start of the training range.
    assert VALIDATION_SEEDS.start > TRAIN_SEEDS.start
    # The grid baseline trains on its scenes, so validation must not study models on them.
    assert NFMP_GRID_SEEDS.stop <= VALIDATION_SEEDS.start or NFMP_GRID_SEEDS.start >= VALIDATION_SEEDS.stop
