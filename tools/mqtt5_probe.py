#!/usr/bin/env python3
"""An outside MQTT 5 client (PyPI paho-mqtt 2.x) for the gateway's tests.

It connects with a persistent session, subscribes to the depth reports and
to a response topic, goes away for --away-s seconds (the broker keeps its
session and queues for it), comes back, sends one command with a response
topic and correlation data, and prints one JSON document on stdout:

  {"before": [report...], "after": [report...], "responses": [response...]}

where a report is {"topic", "frame_id", "expiry_s" (the message expiry
interval the broker delivered it with, or null), "age_s" (now minus the
gateway's received_us)} and a response is {"topic", "correlation", "payload"}.
It stops once it has --reports reports after coming back and a response
whose status is --until-status, or after --timeout-s (exit 1).

Used by crates/stereolink/tests/gateway_mqtt5.rs.
"""

import argparse
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--user", required=True)
    ap.add_argument("--password", required=True)
    ap.add_argument("--prefix", default="stereolink")
    ap.add_argument("--station", default="cam1")
    ap.add_argument("--away-s", type=float, default=3.0)
    ap.add_argument("--reports", type=int, default=10)
    ap.add_argument("--command", default='{"levels": 4}')
    ap.add_argument("--correlation", default="c-42")
    ap.add_argument("--until-status", default="done")
    ap.add_argument("--timeout-s", type=float, default=30.0)
    a = ap.parse_args()

    response_topic = f"{a.prefix}/{a.station}/response/probe"
    lock = threading.Lock()
    state = {"phase": "before", "before": [], "after": [], "responses": []}
    subscribed = threading.Event()

    def on_connect(client, _userdata, _flags, reason_code, _props):
        if reason_code.is_failure:
            print(f"probe: connection refused: {reason_code}", file=sys.stderr)
            return
        client.subscribe(
            [(f"{a.prefix}/+/depth", 1), (f"{a.prefix}/{a.station}/response/#", 1)]
        )

    def on_subscribe(_client, _userdata, _mid, _codes, _props):
        subscribed.set()

    def on_message(_client, _userdata, msg):
        props = msg.properties
        expiry = getattr(props, "MessageExpiryInterval", None) if props else None
        try:
            payload = json.loads(msg.payload)
        except ValueError:
            payload = msg.payload.decode(errors="replace")
        with lock:
            if msg.topic.endswith("/depth"):
                state[state["phase"]].append(
                    {
                        "topic": msg.topic,
                        "frame_id": payload.get("frame_id"),
                        "expiry_s": expiry,
                        "age_s": time.time() - payload["received_us"] / 1e6,
                    }
                )
            else:
                corr = getattr(props, "CorrelationData", None) if props else None
                state["responses"].append(
                    {
                        "topic": msg.topic,
                        "correlation": corr.decode(errors="replace") if corr else None,
                        "payload": payload,
                    }
                )

    def client():
        c = mqtt.Client(
            mqtt.CallbackAPIVersion.VERSION2,
            client_id="mqtt5-probe",
            protocol=mqtt.MQTTv5,
        )
        c.username_pw_set(a.user, a.password)
        c.on_connect, c.on_subscribe, c.on_message = on_connect, on_subscribe, on_message
        connect = Properties(PacketTypes.CONNECT)
        connect.SessionExpiryInterval = 600
        c.connect("127.0.0.1", a.port, keepalive=10, clean_start=False, properties=connect)
        c.loop_start()
        return c

    c = client()
    if not subscribed.wait(10):
        sys.exit("probe: no SUBACK")
    time.sleep(0.5)
    c.disconnect()
    c.loop_stop()
    with lock:
        state["phase"] = "after"
    time.sleep(a.away_s)
    subscribed.clear()
    c = client()
    if not subscribed.wait(10):
        sys.exit("probe: no SUBACK after coming back")
    props = Properties(PacketTypes.PUBLISH)
    props.ResponseTopic = response_topic
    props.CorrelationData = a.correlation.encode()
    c.publish(f"{a.prefix}/{a.station}/set", a.command, qos=1, properties=props)

    def done():
        with lock:
            return len(state["after"]) >= a.reports and any(
                isinstance(r["payload"], dict)
                and r["payload"].get("status") == a.until_status
                for r in state["responses"]
            )

    until = time.time() + a.timeout_s
    while not done() and time.time() < until:
        time.sleep(0.05)
    c.disconnect()
    c.loop_stop()
    with lock:
        del state["phase"]
        print(json.dumps(state))
    sys.exit(0 if done() else 1)


if __name__ == "__main__":
    main()
