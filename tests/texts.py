"""Problem texts shared by several test files."""

# a small trefoil design problem: 40 segments of 5 points, fast enough for sweeps of several items
TINY_TREFOIL = """\
name = "tiny-trefoil"
units = "cm"
[tube]
diameter = 2.43
[target]
curve = "trefoil"
scale = [4.0, 4.0, 4.0]
samples = 41
[actuator]
kind = "tendon"
lambda_min = 0.4
theta_max_deg = 60.0
[design]
points_per_segment = 5
"""
