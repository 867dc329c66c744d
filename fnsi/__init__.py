"""fnsi package."""
