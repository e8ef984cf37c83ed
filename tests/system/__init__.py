"""Whole-system tests (issue 7): fault injection, hostile input, isolation."""
