"""Offline IVFM identification: GK clustering, envelope detection, Gaussian premises,
least-squares consequents, and the data and model file formats (docs/mathematics.md)."""

from autopilot.identification.dataset import (
    CHANNEL_ACCELERATION,
    CHANNEL_FUNCTION,
    CHANNEL_INPUT,
    CHANNELS,
    Dataset,
    DatasetError,
    read_dataset,
    write_dataset,
)
from autopilot.identification.identify import (
    DEFAULT_N_CLUSTERS,
    identify_channel,
    identify_dataset,
)
from autopilot.models.model_file import ModelFileError, load_model, save_model
from autopilot.models.regressors import CHANNEL_REGRESSORS
from autopilot.models.ts_model import (
    ChannelModel,
    FuzzyModelSet,
    It2Model,
    T1Model,
    it2_regressor,
    t1_regressor,
)

__all__ = [
    "CHANNELS",
    "CHANNEL_ACCELERATION",
    "CHANNEL_FUNCTION",
    "CHANNEL_INPUT",
    "CHANNEL_REGRESSORS",
    "DEFAULT_N_CLUSTERS",
    "ChannelModel",
    "Dataset",
    "DatasetError",
    "FuzzyModelSet",
    "It2Model",
    "ModelFileError",
    "T1Model",
    "identify_channel",
    "identify_dataset",
    "it2_regressor",
    "load_model",
    "read_dataset",
    "save_model",
    "t1_regressor",
    "write_dataset",
]
