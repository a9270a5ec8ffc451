"""Simulation: the paper's plant and sensor models, closed-loop scenarios and the compiled closed loop.

Makes synthetic field logs with known truth; above estimate/identify/control (it runs the
controller and the onboard EKF) and below replay.
"""
