// A note on a study or on a trial (GET/PUT /api/v1/studies/{id}/note, /trials/{id}/note):
// free text its owner keeps, shown to every reader as text (never as markup: a note is
// hostile input like any other), editable by whoever may change the study.

import { getJSON, mayManage, saveNote } from './api.js';
import { ago, element } from './html.js';

export const MAX_NOTE_CHARS = 10000; // adclient.schemas.MAX_NOTE_CHARS; the server checks

export class NoteBox {
  /** `path`: the note's URL; `study`: whose owner may edit it. */
  constructor(path, study) {
    this.path = path;
    this.study = study;
    this.note = null;
    this.root = element(`<div class="note" data-note>
      <p class="note-text" data-note-text></p>
      <p class="meta" data-note-meta></p>
      <div data-note-editor hidden>
        <textarea data-note-input rows="5" maxlength="${MAX_NOTE_CHARS}"></textarea>
        <p class="error" data-note-error hidden></p>
        <button type="button" data-note-save>Save</button>
        <button type="button" data-note-cancel>Cancel</button>
      </div>
      <button type="button" class="link" data-note-edit hidden>Edit note</button>
    </div>`);
    this.$ = (name) => this.root.querySelector(`[data-${name}]`);
    this.$('note-edit').addEventListener('click', () => this.edit());
    this.$('note-cancel').addEventListener('click', () => this.show());
    this.$('note-save').addEventListener('click', () => this.save());
  }

  async load() {
    this.note = await getJSON(this.path);
    if (this.$('note-editor').hidden) this.show();
  }

  show() {
    const note = this.note;
    const text = note?.text ?? '';
    const textBox = this.$('note-text');
    textBox.textContent = text || 'No note yet.';
    textBox.classList.toggle('meta', !text);
    this.$('note-meta').textContent = note?.updated_at
      ? `written ${ago(note.updated_at)}${note.updated_by ? ` by ${note.updated_by}` : ''}`
      : '';
    this.$('note-editor').hidden = true;
    const editable = mayManage(this.study);
    this.$('note-edit').hidden = !editable;
    this.$('note-edit').textContent = text ? 'Edit note' : 'Add a note';
  }

  edit() {
    this.$('note-input').value = this.note?.text ?? '';
    this.$('note-error').hidden = true;
    this.$('note-editor').hidden = false;
    this.$('note-edit').hidden = true;
    this.$('note-input').focus();
  }

  /** Save; a refusal (too long, not the owner) is said under the text box, which keeps
   * what was typed. */
  async save() {
    const button = this.$('note-save');
    button.disabled = true;
    try {
      this.note = await saveNote(this.path, this.$('note-input').value);
      this.show();
    } catch (error) {
      this.$('note-error').textContent = String(error.detail ?? error.message);
      this.$('note-error').hidden = false;
    } finally {
      button.disabled = false;
    }
  }
}
