"""Sensor models: functions of ground truth plus a seeded random generator."""
