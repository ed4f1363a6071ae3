"""One module per benchmark task; importing this package registers them all."""

from cnfmp.sim.tasks import (  # noqa: F401
    cube_stacking,
    cup_stacking,
    incline_pick_place,
    language_pick_place,
    wall_avoidance,
)
