// The topic tree as the page builds and reads it: roslink_mqtt/topics.py's TopicTree in JavaScript, over the words
// generated into protocol.mjs (ROSLINK.topics). tests/js/topics.test.mjs checks it against what Python builds and
// parses, case by case: the page has no grammar of its own.
import { ROSLINK } from "./protocol.mjs";

const T = ROSLINK.topics;
const join = (...parts) => parts.join(T.separator);

// "cmd/twist" → [verb, name]; a leaf that is no verb of that direction → [null, leaf] (topics.split_leaf)
function splitLeaf(leaf, sentByUser) {
  const cut = leaf.indexOf(T.separator);
  const head = cut < 0 ? leaf : leaf.slice(0, cut);
  const rest = cut < 0 ? "" : leaf.slice(cut + 1);
  const verb = Object.prototype.hasOwnProperty.call(T.verbs, head) ? T.verbs[head] : null;
  if (!verb || verb.sent_by_user !== sentByUser || Boolean(rest) !== verb.named) return [null, leaf];
  return [head, rest];
}

class TopicTree {
  constructor(prefix) {
    this.prefix = prefix;
    this.depth = prefix.split(T.separator).length;
  }

  heartbeatFilter(robot = T.any) { return join(this.prefix, robot, T.heartbeat); }
  stateFilter(robot = T.any, name = T.rest) { return join(this.prefix, robot, T.state, name); }
  toUserFilter(robot, user) { return join(this.prefix, robot, T.to, user, T.rest); }
  operator(user, clientId) { return join(this.prefix, T.operators, user, clientId); }

  // the topic of `verb` between `user` and `robot`, in the direction the verb goes (TopicTree.user_topic)
  userTopic(robot, user, verb, name = "") {
    const v = T.verbs[verb];
    if (!v) throw new Error(`unknown verb '${verb}'`);
    if (Boolean(name) !== v.named) throw new Error(`'${verb}' ${v.named ? "needs a name" : "takes no name"}`);
    return join(this.prefix, robot, v.sent_by_user ? T.from : T.to, user, ...(name ? [verb, name] : [verb]));
  }

  // a concrete topic, read: {kind, robot, user, name, client_id, verb, leaf}, or null outside the tree
  parse(topic) {
    const parts = topic.split(T.separator);
    if (join(...parts.slice(0, this.depth)) !== this.prefix) return null;
    const rest = parts.slice(this.depth);
    if (!rest.length || rest.some((level) => !level)) return null;
    const out = { kind: null, robot: null, user: null, name: null, client_id: null, verb: null };
    if (rest[0] === T.operators) {
      return rest.length === 3 ? { ...out, kind: T.kinds.operator, user: rest[1], client_id: rest[2] } : null;
    }
    const robot = rest[0];
    if (rest.length === 2 && rest[1] === T.heartbeat) return { ...out, kind: T.kinds.heartbeat, robot };
    if (rest.length === 2 && rest[1] === T.grants) return { ...out, kind: T.kinds.grants, robot };
    if (rest.length >= 3 && rest[1] === T.state) {
      return { ...out, kind: T.kinds.state, robot, name: join(...rest.slice(2)) };
    }
    if (rest.length >= 4 && (rest[1] === T.from || rest[1] === T.to)) {
      const leaf = join(...rest.slice(3));
      const [verb, name] = splitLeaf(leaf, rest[1] === T.from);
      return { ...out, kind: rest[1] === T.from ? T.kinds.from : T.kinds.to, robot, user: rest[2], name, verb };
    }
    return null;
  }
}

// "parameter_events/planner" → "planner"; null for any other state name (topics.param_events_node)
function paramEventsNode(name) {
  const cut = name.indexOf(T.separator);
  if (cut < 0) return null;
  const head = name.slice(0, cut);
  const rest = name.slice(cut + 1);
  return head === T.param_events && rest && !rest.includes(T.separator) ? rest : null;
}

// everything after from/<user>/ or to/<user>/ (cmd/twist): what a parsed topic's verb and name spell
const leafOf = (parsed) => (parsed.verb === null ? parsed.name || "" : parsed.name ? join(parsed.verb, parsed.name)
  : parsed.verb);

export { TopicTree, splitLeaf, leafOf, paramEventsNode };
