// Decodes MCAP bags the way the Foxglove app does when it opens one: @mcap/core reads the
// records, @foxglove/rosmsg parses each channel's ros2msg schema, and
// @foxglove/rosmsg2-serialization decodes every message's CDR. Prints, per file, what each
// channel held and every error as JSON; exits 1 when any message failed to decode.
//
// node decode.mjs BAG.mcap [...]
import { readFileSync } from "node:fs";
import { McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

// JSON of a decoded message: typed arrays as lists (long ones cut), 64-bit integers and
// non-finite floats (JSON has neither) as text.
function plain(value) {
  if (typeof value === "bigint") return value.toString();
  if (typeof value === "number" && !Number.isFinite(value)) return String(value);
  if (ArrayBuffer.isView(value)) {
    const items = Array.from(value.slice(0, 16), plain);
    return value.length > 16 ? { first: items, length: value.length } : items;
  }
  if (Array.isArray(value)) return value.map(plain);
  if (value !== null && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}

function decodeFile(path) {
  const result = { file: path, channels: {}, errors: [] };
  const reader = new McapStreamReader({ validateCrcs: true });
  reader.append(readFileSync(path));
  const schemas = new Map();
  const readers = new Map();
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Schema") {
      schemas.set(record.id, record);
    } else if (record.type === "Channel" && !readers.has(record.id)) {
      // (The summary section repeats every channel after the data.)
      const schema = schemas.get(record.schemaId);
      const channel = { schema: schema?.name, schemaEncoding: schema?.encoding,
                        messageEncoding: record.messageEncoding, messages: 0, decoded: 0 };
      result.channels[record.topic] = channel;
      try {
        const text = new TextDecoder().decode(schema.data);
        readers.set(record.id, { channel, reader: new MessageReader(parse(text, { ros2: true })) });
      } catch (error) {
        result.errors.push(`${record.topic}: schema ${schema?.name} does not parse: ${error}`);
      }
    } else if (record.type === "Message") {
      const entry = readers.get(record.channelId);
      if (!entry) continue;
      entry.channel.messages += 1;
      try {
        const message = entry.reader.readMessage(record.data);
        if (entry.reader.lastReadHadTrailingBytes()) {
          throw new Error("bytes left over after the message: schema and data disagree");
        }
        entry.channel.decoded += 1;
        entry.channel.last = plain(message);
      } catch (error) {
        result.errors.push(`${entry.channel.schema} on channel ${record.channelId}: ${error}`);
      }
    }
  }
  if (!reader.done()) result.errors.push("the file ends before the MCAP footer");
  return result;
}

const results = process.argv.slice(2).map((path) => {
  try {
    return decodeFile(path);
  } catch (error) {
    return { file: path, channels: {}, errors: [`${error}`] };
  }
});
process.stdout.write(JSON.stringify(results) + "\n");
process.exitCode = results.some((r) => r.errors.length) ? 1 : 0;   // exit() would cut a piped stdout
