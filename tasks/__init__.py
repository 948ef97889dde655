"""Tasks: actions, observations, reward, episode end and reset for a robot."""
