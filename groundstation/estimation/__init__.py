"""State estimation: the rigid body's pose and twist at the control period's time, from motion capture, the
modules' gyros and the commanded wrench (:mod:`.filter`), and the pose measurements it takes
(:mod:`.measurement`). The flight loop's only source of state."""
