// fleetbus's AMQP contract as a robot in another language reads it: the AsyncAPI document that
// `fleetbus schemas DIR` writes (asyncapi.json), and nothing else. Where to publish, with which
// routing key and AMQP properties, which body fields are required, the size limit, the inbox, the
// service calls and their replies: each is looked up in the document here, never copied from the
// Python client. Messages are checked against the document's own JSON Schemas with Ajv (AsyncAPI
// 2.6 schemas are a superset of JSON Schema draft 07).

import { randomBytes } from "node:crypto";
import { readFileSync } from "node:fs";

import AjvModule from "ajv";
import addFormatsModule from "ajv-formats";

const Ajv = AjvModule.default ?? AjvModule;
const addFormats = addFormatsModule.default ?? addFormatsModule;
const DOCUMENT_ID = "asyncapi.json";

// AMQP property names as the document writes them (AMQP 0-9-1's), and as amqplib takes them
const OPTION_NAMES = {
  user_id: "userId",
  content_type: "contentType",
  delivery_mode: "deliveryMode",
  message_id: "messageId",
  reply_to: "replyTo",
  correlation_id: "correlationId",
  expiration: "expiration",
};

export class Contract {
  constructor(path) {
    this.document = JSON.parse(readFileSync(path, "utf8"));
    if (!String(this.document.asyncapi).startsWith("2.")) {
      throw new Error(`${path} is AsyncAPI ${this.document.asyncapi}, not 2.x`);
    }
    this.ajv = new Ajv({ strict: false, allErrors: true });
    addFormats(this.ajv);
    this.ajv.addSchema(this.document, DOCUMENT_ID);
    this.validators = new Map();
  }

  resolve(ref) {
    if (!ref.startsWith("#/")) throw new Error(`only local references are followed, not ${ref}`);
    return ref
      .slice(2)
      .split("/")
      .reduce((node, key) => {
        const found = node?.[key.replaceAll("~1", "/").replaceAll("~0", "~")];
        if (found === undefined) throw new Error(`the document has no ${ref}`);
        return found;
      }, this.document);
  }

  // A message with its traits applied (AsyncAPI 2: the message's own fields win over its traits').
  message(ref) {
    const message = this.resolve(ref);
    const traits = (message.traits ?? []).map((trait) => (trait.$ref ? this.resolve(trait.$ref) : trait));
    return Object.assign({}, ...traits, message);
  }

  server() {
    const [server] = Object.values(this.document.servers);
    return server;
  }

  // Whether `value` is valid against the schema at `pointer` ("#/components/..."), and why not.
  check(pointer, value) {
    let validate = this.validators.get(pointer);
    if (validate === undefined) {
      validate = this.ajv.compile({ $ref: DOCUMENT_ID + pointer });
      this.validators.set(pointer, validate);
    }
    const valid = validate(value);
    return { valid, errors: valid ? [] : validate.errors.map((e) => `${e.instancePath || "/"} ${e.message}`) };
  }

  // The message of `components.messages` whose AMQP binding names `type` (an event type or a method).
  messageOfType(type, usedBy = () => true) {
    for (const [name, message] of Object.entries(this.document.components.messages)) {
      const ref = `#/components/messages/${name}`;
      if (message.bindings?.amqp?.messageType === type && usedBy(ref)) return ref;
    }
    throw new Error(`the document has no message of type ${type}`);
  }

  // The channel where `operation` ("publish", "subscribe") carries the message `ref`.
  channelOf(operation, ref, kind = null) {
    for (const [name, channel] of Object.entries(this.document.channels)) {
      const op = channel[operation];
      if (!op || (kind && channel.bindings?.amqp?.is !== kind)) continue;
      if ((op.message.oneOf ?? [op.message]).some((message) => message.$ref === ref)) {
        return { name, channel, operation: op };
      }
    }
    throw new Error(`the document has no channel to ${operation} ${ref}`);
  }

  published(ref) {
    return Object.values(this.document.channels).some((channel) => {
      const message = channel.publish?.message;
      return message && (message.oneOf ?? [message]).some((m) => m.$ref === ref);
    });
  }

  // amqplib's publish options from the message's `x-amqp-properties` and the operation's AMQP
  // binding; `given`: the values only the caller knows (message_id, correlation_id, ...).
  publishOptions(message, binding, robot, given = {}) {
    const wanted = message["x-amqp-properties"];
    const options = { mandatory: binding.mandatory === true };
    for (const [name, property] of Object.entries(wanted.properties)) {
      let value = given[name];
      if (value === undefined && "const" in property) value = property.const;
      if (value === undefined && name === "user_id") value = fill(binding.userId, robot);
      if (value === undefined && name === "delivery_mode") value = binding.deliveryMode;
      if (value !== undefined) options[OPTION_NAMES[name]] = value;
    }
    const missing = wanted.required.filter((name) => options[OPTION_NAMES[name]] === undefined);
    if (missing.length) throw new Error(`no value for the required properties ${missing.join(", ")}`);
    if (message.bindings?.amqp?.messageType) options.type = message.bindings.amqp.messageType;
    return options;
  }

  // Where and how a robot publishes an event of `type`.
  event(type, robot) {
    const ref = this.messageOfType(type, (candidate) => this.published(candidate));
    const { name, channel, operation } = this.channelOf("publish", ref);
    const message = this.message(ref);
    return {
      ref,
      message,
      exchange: fill(channel.bindings.amqp.exchange.name, robot),
      routingKey: fill(name, robot),
      schema: message.payload.$ref,
      maxBytes: message["x-max-body-bytes"],
      options: (given) => this.publishOptions(message, operation.bindings.amqp, robot, given),
    };
  }

  // An event's envelope: exactly the fields the payload schema requires, each from what the robot
  // knows, and `extra` (optional fields) beside them.
  envelope(schemaRef, known, extra = {}) {
    const schema = this.resolve(schemaRef);
    const envelope = {};
    for (const field of schema.required) {
      if (field === "type") envelope.type = schema.properties.type.const;
      else if (field in known) envelope[field] = known[field];
      else throw new Error(`${schemaRef} requires ${field}, which this robot does not know how to fill`);
    }
    return { ...envelope, ...extra };
  }

  // A new epoch as the envelope's schema describes it: UTC time to the millisecond, random hex.
  newEpoch(schemaRef) {
    const stamp = new Date().toISOString().replace(/[-:]/g, "").replace(".", "");
    const epoch = `${stamp.slice(0, 8)}T${stamp.slice(9, 18)}Z-${randomBytes(4).toString("hex")}`;
    const pattern = this.resolve(schemaRef).properties.epoch.pattern;
    if (!new RegExp(pattern).test(epoch)) throw new Error(`epoch ${epoch} does not match ${pattern}`);
    return epoch;
  }

  // The queue a robot reads its notifications from.
  inbox(robot) {
    const ref = "#/components/messages/notification";
    const { channel, operation } = this.channelOf("subscribe", ref, "queue");
    return {
      queue: fill(channel.bindings.amqp.queue.name, robot),
      ack: operation.bindings?.amqp?.ack !== false,
      schema: this.resolve(ref).payload.$ref,
    };
  }

  // Where and how a robot calls the service `method`, and where its reply comes.
  service(method, robot) {
    const ref = this.messageOfType(method, (candidate) => this.published(candidate));
    const { name, channel, operation } = this.channelOf("publish", ref);
    const replyRef = operation["x-reply"].$ref;
    const reply = this.channelOf("subscribe", replyRef, "queue");
    const message = this.message(ref);
    return {
      exchange: fill(channel.bindings.amqp.exchange.name, robot),
      routingKey: fill(name, robot),
      params: `${ref}/payload`,
      reply: `${replyRef}/payload`,
      replyQueue: reply.channel.bindings.amqp.queue.name,
      replyNoAck: reply.operation.bindings?.amqp?.ack === false,
      options: (given) => this.publishOptions(message, operation.bindings.amqp, robot, given),
    };
  }

  // The reasons the dead-letter channel documents.
  reasons() {
    for (const channel of Object.values(this.document.channels)) {
      if (channel["x-reasons"]) return channel["x-reasons"];
    }
    throw new Error("the document lists no dead-letter reasons");
  }
}

export function fill(template, robot) {
  return template.replaceAll("{robot}", robot);
}
