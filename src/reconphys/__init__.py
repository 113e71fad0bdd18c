"""reconphys: one monocular video of a dropped deformable object → a simulation-ready asset.

3D Gaussians (appearance) bound to a spring-mass system (mass, stiffness, damping, ground
friction). Conventions (SI units, z up, ground z = 0, frame_dt 0.03 s) are in docs/ and DESIGN.md.
"""

__version__ = "0.1.0"
