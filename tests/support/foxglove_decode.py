"""Decode the view's messages as a Foxglove client does: protobuf by the schema the channel carries, JSON as JSON."""

from __future__ import annotations

import json


def decoder(schema_name: str, encoding: str, data: bytes):
    """A function of a message's bytes to a dict, for one channel (``encoding``: the schema's)."""
    if encoding in ("jsonschema", "") or schema_name.startswith("companion."):
        return lambda raw: json.loads(raw)
    assert encoding == "protobuf", encoding
    from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))

    def decode(raw: bytes) -> dict:
        return json_format.MessageToDict(cls.FromString(raw), preserving_proto_field_name=True)

    return decode


def read_mcap(path) -> dict[str, list]:
    """Every message of an MCAP file, decoded, per topic: ``{topic: [(log_time_ns, schema name, dict), ...]}``."""
    from mcap.reader import make_reader

    out: dict[str, list] = {}
    decoders = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.id not in decoders:
                decoders[channel.id] = decoder(schema.name, schema.encoding, schema.data)
            out.setdefault(channel.topic, []).append((message.log_time, schema.name, decoders[channel.id](message.data)))
    return out
