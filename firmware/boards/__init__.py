"""Example board configurations (copy one to the board root as tcomp_board.py)."""
