"""Swarm robotics: task partitioning in foraging swarms (seed 09)."""
