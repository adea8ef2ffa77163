"""The goal planner's node: image goals to subgoals over Zenoh, and the client that sends goals."""
