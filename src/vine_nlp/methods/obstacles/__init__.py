"""Design among obstacles (issue 15): the one transcription plus rows that keep the tube outside every obstacle.

- ``rows``: the rows, per-stage blocks of the samples' distances to the obstacles (the model's formulas
  with the obstacles as data), and the intermediate shapes of actuation after growth;
- ``plan``: what the rows need round by round: samples, requirements, active sets, shapes with rows;
- ``push``: a start around the obstacles, the target (or a chain) pushed out and designed;
- ``design``: the design's active-set loop on the drive, and the weights of blocked target points;
- ``tip``: tip problems among obstacles, starts on the drive, each an active-set loop."""

from vine_nlp.methods.obstacles.design import METHOD, RUN, START_RUN, design_with_obstacles
from vine_nlp.methods.obstacles.tip import design_tip_with_obstacles, tip_design

__all__ = ["START_RUN", "METHOD", "RUN", "design_with_obstacles", "design_tip_with_obstacles", "tip_design"]
