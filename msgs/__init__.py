"""Typed message definitions, one module per domain (std, geometry, sensor, sonar, nav, control, can, sets, slam, swarm, vision)."""
