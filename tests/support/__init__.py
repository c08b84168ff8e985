"""Helpers that only the tests import (scenes, fake workers, repository paths)."""
