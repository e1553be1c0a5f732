"""The planning scene: the one world model (planning_scene.py)."""
