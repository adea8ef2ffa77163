"""The map-lite topo-metric map: keyframes, covisibility and connectivity graphs, I/O."""
