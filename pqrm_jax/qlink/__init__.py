"""Q-Link (provisional)."""
