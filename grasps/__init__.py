"""The bundled grasp library, importable as the resource package ``planner.grasps``
(pyproject.toml maps this folder there; ``planner.resources`` finds the files by name)."""
