#!/usr/bin/env python3
"""Writes xbee_vectors.txt: XBee API frames built by Digi's own Python library
(PyPI `digi-xbee`, offline), in API mode 1 and 2, one per line as
`name mode hex`. The Rust test `tests/xbee_golden.rs` parses every line with
stereolink's parser and re-encodes it byte for byte.

    pip install digi-xbee && python3 crates/link/tests/golden/make_xbee_vectors.py
"""
import os

from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress
from digi.xbee.models.mode import OperatingMode
from digi.xbee.models.status import ATCommandStatus, DiscoveryStatus, ModemStatus, TransmitStatus
from digi.xbee.packets.common import (ATCommPacket, ATCommResponsePacket, ModemStatusPacket, ReceivePacket,
                                      TransmitPacket, TransmitStatusPacket)
from digi.xbee.packets.raw import RX16Packet, RX64Packet, TX16Packet, TX64Packet, TXStatusPacket

A64 = XBee64BitAddress.from_hex_string("0013A20040A1B2C3")
A16 = XBee16BitAddress.from_hex_string("7D11")  # needs escaping in mode 2
Z16 = XBee16BitAddress.from_hex_string("FFFE")  # 16-bit address unknown
M16 = XBee16BitAddress.from_hex_string("7D84")
DATA = bytes([0x7E, 0x00, 0x11, 0x13, 0x7D]) + b"stereolink"


def packets(mode):
    return [
        ("tx16", TX16Packet(0x87, XBee16BitAddress.from_hex_string("1234"), 0, b"TxData", op_mode=mode)),
        ("tx16_escapes", TX16Packet(0x13, A16, 0, DATA, op_mode=mode)),
        ("tx64", TX64Packet(0x01, A64, 0, DATA, op_mode=mode)),
        ("rx16", RX16Packet(XBee16BitAddress.from_hex_string("1234"), 0x5E, 1, b"TxData", op_mode=mode)),
        ("rx64", RX64Packet(A64, 0x28, 0, DATA, op_mode=mode)),
        ("tx_status", TXStatusPacket(0x01, TransmitStatus.SUCCESS, op_mode=mode)),
        ("zb_tx", TransmitPacket(0x52, A64, XBee16BitAddress.from_hex_string("FFFE"), 0, 0, DATA, op_mode=mode)),
        ("zb_tx_status", TransmitStatusPacket(0x52, A16, 2, TransmitStatus.SUCCESS, DiscoveryStatus.NO_DISCOVERY_OVERHEAD, op_mode=mode)),
        ("zb_rx", ReceivePacket(A64, A16, 1, DATA, op_mode=mode)),
        ("at_np", ATCommPacket(0x52, "NP", op_mode=mode)),
        ("at_np_response", ATCommResponsePacket(0x52, "NP", ATCommandStatus.OK, bytes([0x00, 0x64]), op_mode=mode)),
        # The fields of the worked examples in Digi's Zigbee RF module manual.
        ("manual_zb_tx", TransmitPacket(0x01, XBee64BitAddress.from_hex_string("0013A200400A0127"), Z16, 0, 0,
                                        b"TxData0A", op_mode=mode)),
        ("manual_zb_tx_status", TransmitStatusPacket(0x01, M16, 0, TransmitStatus.SUCCESS,
                                                     DiscoveryStatus.ADDRESS_DISCOVERY, op_mode=mode)),
        ("manual_zb_rx", ReceivePacket(XBee64BitAddress.from_hex_string("0013A20040522BAA"), M16, 1, b"RxData",
                                       op_mode=mode)),
        ("manual_at_nj", ATCommPacket(0x52, "NJ", op_mode=mode)),
        ("manual_at_bd_response", ATCommResponsePacket(0x01, "BD", ATCommandStatus.OK, op_mode=mode)),
        ("manual_modem_status", ModemStatusPacket(ModemStatus.COORDINATOR_STARTED, op_mode=mode)),
        # What a radio answers when asked (values of an XBee S2C in Zigbee router API firmware).
        ("at_vr_response", ATCommResponsePacket(0x02, "VR", ATCommandStatus.OK, bytes([0x40, 0x5F]), op_mode=mode)),
        ("at_sh_response", ATCommResponsePacket(0x03, "SH", ATCommandStatus.OK, bytes.fromhex("0013A200"),
                                                op_mode=mode)),
        ("at_op_invalid", ATCommResponsePacket(0x04, "OP", ATCommandStatus.INVALID_COMMAND, op_mode=mode)),
        ("zb_tx_status_address_not_found", TransmitStatusPacket(0x05, Z16, 0, TransmitStatus.ADDRESS_NOT_FOUND,
                                                                DiscoveryStatus.ADDRESS_DISCOVERY, op_mode=mode)),
        ("tx_status_no_ack", TXStatusPacket(0x06, TransmitStatus.NO_ACK, op_mode=mode)),
        ("modem_status_reset", ModemStatusPacket(ModemStatus.HARDWARE_RESET, op_mode=mode)),
    ]


def main():
    lines = []
    for label, mode in (("1", OperatingMode.API_MODE), ("2", OperatingMode.ESCAPED_API_MODE)):
        for name, p in packets(mode):
            lines.append(f"{name} {label} {p.output(escaped=(label == '2')).hex()}")
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xbee_vectors.txt")
    with open(out, "w") as f:
        f.write("# XBee API frames from Digi's digi-xbee library: name, API mode, bytes (hex)\n")
        f.write("\n".join(lines) + "\n")
    print(f"wrote {len(lines)} vectors to {out}")


if __name__ == "__main__":
    main()
