# Training-set size per task (sourced, not run): the paper's low-data column (wall 10, incline
# 20, cup 20, cube 30 demonstrations); 30 for language_pick_place and 20 for bar_into_tray,
# which the paper does not table; drawer_place 4, the paper's Fig. 5. Every task's models are
# trained on `cnfmp dataset generate --task T --episodes N --seed 0`. bar_into_tray has no
# shipped model: it is the task that checks the default recipe (scripts/bench-seeds.sh).
declare -A DEMOS=([wall_avoidance]=10 [incline_pick_place]=20 [cup_stacking]=20 [cube_stacking]=30
                  [language_pick_place]=30 [bar_into_tray]=20 [drawer_place]=4)
