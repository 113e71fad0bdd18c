"""``python -m reconphys.cli`` (also what ``torchrun -m reconphys.cli train`` runs)."""

from . import main

main()
