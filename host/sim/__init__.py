"""Feed-axis digital twin (placeholder docstring, completed below)."""
