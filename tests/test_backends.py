import pytest

from slr_ray import InputValueError
from slr_ray.backends import Backend, available_backends, get_backend


def test_registry():
    assert available_backends()[0] == "binning" and "embree" in available_backends()
    assert callable(get_backend("binning")) and callable(get_backend(Backend.EMBREE))
    with pytest.raises(InputValueError, match="unknown backend"):
        get_backend("optix")
