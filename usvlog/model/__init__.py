"""The paper's vessel model and the maths shared by every stage: frames and angles, dynamics, error measures.

Pure numpy, the lowest layer above the base modules (errors, resources); everything else builds on it.
"""
