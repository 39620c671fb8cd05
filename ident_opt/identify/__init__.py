"""Estimators of the parameters π: all linear-in-π ones work from sufficient statistics (`stats.Stats`)."""
