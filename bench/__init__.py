"""Experiments, scoring, recording and reports; the only package that knows both sim and rig."""
