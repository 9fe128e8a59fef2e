"""DMIS programs the stop and run-end tests share: the simulator's part at its true place (190, 150, 0)."""

from __future__ import annotations

# three hits on the front face of the simulator's part
FRONT_FACE = """F(FRONT) = FEAT/PLANE, CART, 60, 0, 20, 0, -1, 0
MEAS/PLANE, F(FRONT), 3
  PTMEAS/CART, 20, 0, 20, 0, -1, 0
  PTMEAS/CART, 60, 0, 30, 0, -1, 0
  PTMEAS/CART, 100, 0, 20, 0, -1, 0
ENDMES
"""
APPROACH = "SNSET/APPRCH, 5\nSNSET/RETRCT, 5\n"


def program(name: str, *blocks: str) -> str:
    """A whole program: its name, millimetres, the part's set-up, the blocks, ENDFIL."""
    return (f"FILNAM/'{name}'\nUNITS/MM, ANGRAD\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\n"
            + "".join(blocks) + "ENDFIL\n")
