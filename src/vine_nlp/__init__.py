"""vine_nlp: inverse design of actuator routings for vine robots.

Model after Blumenschein et al., "Geometric Solutions for General Actuator
Routing on Inflated-Beam Soft Growing Robots", IEEE T-RO 2021.
"""

__version__ = "0.1.0"
