"""Behaviour (seed 000 sections 8-9): traffic rules, the moving-traffic check, the hierarchical state machine."""
