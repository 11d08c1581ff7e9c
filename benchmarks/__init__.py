"""The benchmark's committed results (results/) and its experiments (experiments/)."""
