"""The onboard service: the localization core, its stage threads and child processes, and its assembly."""
