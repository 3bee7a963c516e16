"""Layer 3: design methods over one Problem, each returning one Result."""
