"""Reads an incise recording with MCAP's own Python libraries, nothing of ours: every channel,
every message decoded with the protobuf schema embedded in the file. Prints one JSON line:
messages per topic, the schema names, the metadata and attachments. Exits 1 if a message does not
decode.

    python check_mcap.py RECORDING.mcap
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path: str) -> int:
    topics: dict = {}
    schemas: dict = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, proto in reader.iter_decoded_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
            schemas[channel.topic] = schema.name
            # A decoded message re-encodes to the bytes it came from.
            if proto.SerializeToString() != message.data:
                print(f"{channel.topic}: message {message.sequence} does not round-trip")
                return 1
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = [a.name for a in reader.iter_attachments()]
    print(json.dumps({"topics": topics, "schemas": schemas, "metadata": metadata,
                      "attachments": attachments}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
