"""``steval replay``: decode a capture and summarise it (placeholder until the link core lands)."""
