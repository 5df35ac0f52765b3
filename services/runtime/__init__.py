"""What every service runs on: the Zenoh session (``session``), bounded mailboxes
(``mailbox``), frames (``frames``), the typed bus (``bus``, ``local_delivery``), deployment
files (``config``), the service context and clock (``context``, ``clock``), the registry of
services and the launcher (``registry``, ``launcher``)."""

from services.runtime.bus import Bus
from services.runtime.clock import Ticker, age_s
from services.runtime.config import ConfigError, Deployment, ServiceSettings, load_deployment
from services.runtime.context import ServiceContext
from services.runtime.frames import Frame, FrameError, decode_image, encode_frame
from services.runtime.launcher import run_deployment
from services.runtime.mailbox import Rejections, Subscription
from services.runtime.session import LOCAL_ENDPOINT, ZenohSettings, open_session

__all__ = ["LOCAL_ENDPOINT", "Bus", "ConfigError", "Deployment", "Frame", "FrameError",
           "Rejections", "ServiceContext", "ServiceSettings", "Subscription", "Ticker",
           "ZenohSettings", "age_s", "decode_image", "encode_frame", "load_deployment",
           "open_session", "run_deployment"]
