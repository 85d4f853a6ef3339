"""The monitor's settings key over Zenoh (R29): a real zenoh peer on 127.0.0.1 changes rho, a
stale limit and the monitored cameras of a running monitor; a bad message changes nothing."""

from __future__ import annotations

import json
import threading

import pytest

from depthguard.transport.settings import zenoh_config
from loopback import free_port, wait_until






@pytest.mark.multiprocess
def test_settings_key_changes_a_running_monitor_and_refuses_bad_messages():
    import zenoh

    from depthguard.runtime import Monitor
    from depthguard.runtime.remote import SettingsListener, settings_keys
    from depthguard.sim import load_cell

    rig = load_cell("flacco-cell").rig
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    mon_session = zenoh.open(zenoh_config(listen=[endpoint]))
    admin = zenoh.open(zenoh_config(listen=["tcp/127.0.0.1:0"], connect=[endpoint]))
    results, lock = [], threading.Lock()
    key, result_key = settings_keys("cellA")

    def on_result(sample):
        with lock:
            results.append(json.loads(sample.payload.to_bytes().decode()))

    sub = admin.declare_subscriber(result_key, on_result)
    pub = admin.declare_publisher(key)
    with Monitor(rig) as mon:
        listener = SettingsListener(mon, mon_session, "cellA")
        try:
            assert wait_until(lambda: pub.matching_status.matching, 10.0)
            before = mon.config
            pub.put(json.dumps({"rho": 0.3, "camera_stale_s": 0.2, "cameras": ["cam0"]}).encode())
            assert wait_until(lambda: len(results) >= 1, 5.0)
            assert results[0]["ok"], results[0]
            assert mon.config.rho == 0.3 and mon.config.camera_stale_limit == 0.2
            assert mon.camera_ids == ("cam0",) and results[0]["cameras"] == ["cam0"]
            # every bad message is refused whole, with a sentence, and changes nothing
            for bad, words in ((b"not json", "Expecting"), (json.dumps({"rho": -1}).encode(), "rho"),
                               (json.dumps({"rho": 0.2, "cameras": ["nope"]}).encode(), "nope"),
                               (json.dumps({"principal": "cam1"}).encode(), "cannot change principal")):
                n = len(results)
                pub.put(bad)
                assert wait_until(lambda: len(results) > n, 5.0)
                assert results[-1]["ok"] is False and words in results[-1]["error"], results[-1]
                assert mon.config.rho == 0.3 and mon.camera_ids == ("cam0",)
            pub.put(json.dumps({"cameras": ["cam0", "cam1"]}).encode())
            assert wait_until(lambda: results[-1].get("cameras") == ["cam0", "cam1"], 5.0)
            assert mon.camera_ids == ("cam0", "cam1") and before.rho == 0.4
            assert listener.applied == 2 and listener.rejected == 4
        finally:
            listener.close()
            sub.undeclare()
            pub.undeclare()
            admin.close()
            mon_session.close()
