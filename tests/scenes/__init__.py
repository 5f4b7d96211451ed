"""Tests of the scenes area."""
