"""Datasets: LeRobot v3.0 writing (from the simulator) and reading."""
