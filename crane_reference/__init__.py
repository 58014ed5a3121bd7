"""Programmed constrained motion of a flexible-boom crane (Jarzebowska, Urbas, Augustynek)."""
