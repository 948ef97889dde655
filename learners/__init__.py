"""Learners: tabular Q-learning and the replay-buffer DQN family."""
