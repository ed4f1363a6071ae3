"""One module per benchmark task; importing this package registers them all."""

from cnfmp.sim.tasks import cube_stacking, cup_stacking, incline_pick_place, wall_avoidance  # noqa: F401
