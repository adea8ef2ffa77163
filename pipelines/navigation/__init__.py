"""Image-goal navigation on the map: goal localization, Dijkstra, subgoal tracking."""
