"""Offline tools: map building, recording, simulated passes and simulated navigation runs."""
