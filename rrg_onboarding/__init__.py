"""Onboarding a lab's own objects: ``rrg-object``."""
