"""Names the CLI offers as choices, in a module without heavy imports: ``--help`` lists them (click.Choice) without
importing numpy, and the modules that implement them take their names from here, so the two cannot drift."""

SYMMETRY_GROUPS: tuple[str, ...] = ("C4", "D4", "none")
"""Isomorphism groups of lattice configurations (:data:`groundstation.assembly.lattice.GROUPS`)."""
SAMPLING_SCHEMES: tuple[str, ...] = ("compact", "uniform", "spread")
"""Weights of Algorithm 1's sampling (:class:`groundstation.design.enumeration.SamplingPolicy`)."""
MOCAP_SYSTEMS: tuple[str, ...] = ("vicon", "optitrack", "qualisys", "vrpn", "mock")
"""Motion-capture systems the bridge reads through the ``motioncapture`` package (:mod:`groundstation.mocap.bridge`)."""
