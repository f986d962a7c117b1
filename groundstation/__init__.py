"""Ground station and design pipeline for downwash-aware modular aerial systems.

The package follows the pipeline of the paper (Li & Koeppl, *Downwash-aware configuration optimization for
modular aerial systems*): ``assembly`` holds the one model of an assembly every stage shares, ``design``
enumerates and optimizes configurations.
"""

__version__ = "0.1.0"
