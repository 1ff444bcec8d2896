"""The bundled hands, importable as the resource package ``planner.robots`` (pyproject.toml
maps this folder there; ``planner.resources`` finds them). One folder per hand: hand.yaml + URDF."""
