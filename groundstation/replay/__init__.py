"""Reading flight logs back: streamed reading, the figure-8 analysis, offline re-runs and figures."""
