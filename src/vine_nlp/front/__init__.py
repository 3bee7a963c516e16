"""Layer 5: figures, fabrication templates, sweeps and the command line."""
